"""Config schema of the ``eval`` node: the fixed evaluation suite, its conditions and its outputs.

The suite is drawn from its own generator (``eval.seed``), never from training's, so every policy and every
periodic evaluation of one run meets exactly the same episodes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from diana_lab.config.sensing import MAX_RAYS
from diana_lab.config.store import register
from diana_lab.config.validation import (
    ConfigError,
    check_seed,
    in_range,
    length,
    non_negative,
    non_negative_int,
    one_of,
    ordered,
    positive,
    positive_int,
)

DYNAMICS_OPTIONS = ("kinematic", "physics")


@dataclass
class ShieldCameraConfig:
    """A depth camera that feeds only the slope shield's map (a hazard camera; the policy never sees it). It
    takes the env sensor's noise (``sensor.noise``, ``sensor.noise_level``). ``yaw_deg`` turns it from the
    rover's heading (left positive); ``mount_xyz`` is its position in the rover frame turned by ``yaw_deg`` (x
    along where it looks), so four cameras at 0, 90, 180 and -90 deg with the same ``mount_xyz`` stand round
    the mast."""

    yaw_deg: float = 0.0
    mount_xyz: list[float] = field(default_factory=lambda: [0.2, 0.0, 1.0])
    pitch_deg: float = 40.0  # down
    width: int = 256
    height: int = 192
    hfov_deg: float = 87.0
    vfov_deg: float = 58.0
    max_range: float = 6.0  # m

    def check(self, key: str) -> None:
        """Raise a :class:`ConfigError` naming ``key`` (``eval.shield.cameras[i]``) for a bad value."""
        in_range(f"{key}.yaw_deg", self.yaw_deg, -180.0, 180.0)
        length(f"{key}.mount_xyz", self.mount_xyz, 3)
        for i, v in enumerate(self.mount_xyz):
            in_range(f"{key}.mount_xyz[{i}]", v, -5.0, 5.0)
        in_range(f"{key}.pitch_deg", self.pitch_deg, -90.0, 90.0)
        positive_int(f"{key}.width", self.width)
        positive_int(f"{key}.height", self.height)
        if self.width * self.height > MAX_RAYS:
            raise ConfigError(f"{key}: expected at most {MAX_RAYS} pixels, got {self.width} x {self.height}")
        in_range(f"{key}.hfov_deg", self.hfov_deg, 0.0, 180.0, inclusive=False)
        in_range(f"{key}.vfov_deg", self.vfov_deg, 0.0, 180.0, inclusive=False)
        positive(f"{key}.max_range", self.max_range)


@dataclass
class ShieldConfig:
    """The slope shield (:mod:`diana_lab.shield.slope_shield`): before a learnt policy's candidate waypoint is
    driven, the rover's own fine height map checks the straight drive to it; among the policy's ``top_k``
    most probable candidates the first it does not see too steep is driven. Only for discrete action spaces."""

    enabled: bool = False
    cell_size: float = 0.2  # m: the shield's own height map of the sensor's returns (finer than the policy's)
    limit_deg: float = 25.0  # veto a drive where the map shows a pitch or roll above this (unknown ground passes)
    # candidates tried, most probable first; if all are vetoed, the first not near a hazard felt and not obstructed
    # (its tilt check dropped; away from places stood on first), else the policy's own choice, is driven
    top_k: int = 16
    spacing: float = 0.2  # m between the checks along the drive
    radius: float = 64.0  # m: half-width of the square the map covers around the episode's first pose
    # m: also veto a drive passing this close to where the wheels met ground they could not drive this episode
    # (the rover's tilt guard tripped, robot.tilt_guard_deg, or a slope held it: ``hazard_xy``); 0: off
    hazard_radius: float = 0.0
    # m: also veto a drive where the map shows anything within the rover's footprint (robot.radius) rising more
    # than this above its highest wheel probe (a rock between or beside the wheels); 0: off
    obstacle_height: float = 0.0
    # m: the shield's map leaves out returns nearer than this to the sensor (spurious dust returns live there,
    # and the lidar never looks again at the ground beside the rover to overwrite them); 0: maps every return
    min_range: float = 0.0
    # m: among the allowed candidates, drive the first that ends at least this far from every place the rover
    # stood at an earlier decision of the episode (the first allowed if none does): no loops back; 0: off
    revisit_radius: float = 0.0
    # m: also veto a drive where a cell of the map within the rover's footprint stands more than this above its
    # 8 neighbours (``peak_rank``: a rock, which the obstacle check misses when a wheel probe lies on it); 0: off
    peak_height: float = 0.0
    # what the peak check compares a cell with: 0 the median of its known neighbours; k >= 1 the k-th highest of
    # them (2: a ridge, with two neighbours along it at its own height, never stands out; a rock one or two
    # cells wide does)
    peak_rank: int = 0
    # the peak check judges a cell only with at least this many of its 8 neighbours known (1..8): next to
    # unseen ground there may be no ground to judge it against
    peak_min_known: int = 7
    # m: with the goal this near, first the shortest of the top_k candidates whose straight drive passes within
    # ``approach_tolerance`` of it (none does: the one passing nearest), if the checks allow it; 0: off
    approach_radius: float = 0.0
    approach_tolerance: float = 0.3  # m; under episode.goal_tolerance, so that the drive's own error is allowed for
    # m: where the ground the map shows within ``smooth_radius`` of the rover is smoother than this (the median
    # departure of a 2 x 2-cell block from the mean of its 4 neighbours: 0 on any plane), veto a drive whose
    # footprint rises more than ``smooth_obstacle_height`` above its wheels (instead of ``obstacle_height``): on
    # smooth ground a low rock stands out, on rough ground the same rise is the ground's own relief; 0: off
    smooth_roughness: float = 0.0
    smooth_obstacle_height: float = 0.0  # m, below obstacle_height
    smooth_radius: float = 3.0  # m
    # once this many decisions (each from a new place) have passed without the rover coming ``detour_progress`` m
    # nearer the goal than ever, drive the allowed candidate with the least length + cost to go from its end over
    # the shield's map (slopes over limit_deg for every heading and hazards felt untraversable, unseen ground
    # drivable; searched within ``detour_margin`` of the rover and the goal): round a wall, not along it; 0: off
    detour_after: int = 0
    detour_progress: float = 0.5  # m
    detour_margin: float = 10.0  # m
    # the relief check (diana_lab.shield.relief): veto a drive crossing a cell whose footprint (robot.radius + 0.1 m)
    # on the map's mean returns is steeper than relief_slope_deg, holds a step (de-tilted, between neighbouring
    # cells) over relief_step or is rougher than relief_roughness (RMS about its plane), judged where at least
    # relief_min_known of the footprint's cells are known; the detour's search takes those cells as walls. The
    # limits are the A* cost map's lethal ones for the Jackal. Worth it only with returns dense near the rover
    # (``cameras``): from the lidar's alone it changed nothing (docs/reference_policy.md, "Hazard cameras")
    relief: bool = False
    relief_slope_deg: float = 22.0
    relief_step: float = 0.08  # m
    relief_roughness: float = 0.065  # m
    relief_min_known: int = 8
    # m: with the relief check on, also veto a drive that, more than this far along it, crosses a cell the check
    # cannot judge (unseen, or too little of its footprint seen): with the cameras' dense map that is ground hidden
    # behind a crest or down a slope, where the physics rover rolled; 0: off
    relief_unseen_from: float = 0.0
    # the route rule: at every decision (after the final approach and a stalled rover's detour), only the drives
    # the checks allow whose length + cost to go over the shield's map (the detour's search) lies within
    # route_tolerance m of the least are open to the policy, its most probable of them driven: the policy
    # chooses among the ways to the goal its map shows, not against them (diana_lab.shield.detour); off: false
    route: bool = False
    route_tolerance: float = 1.0  # m
    # the search's cost of slope (the detour's and the route rule's): a cell whose map slope (the steepest, from
    # its 4 neighbours) lies over slope_cost_from_deg costs its length times 1 + slope_cost_weight x (the excess
    # over the span up to slope_cost_to_deg, at most 1)^2, as the A* oracle's cost map charges wheel pitch;
    # 0: every drivable cell costs its length
    slope_cost_weight: float = 0.0
    slope_cost_from_deg: float = 15.0
    slope_cost_to_deg: float = 22.0
    # m: a map of the site made before the drive (an orbital elevation model, a competition yard's survey): the
    # world's terrain (not its obstacles) averaged over squares this wide, whose slope the search (the detour's
    # and the route rule's) reads where the shield's own map gives no slope (unseen, or beside unseen ground),
    # instead of taking that ground as flat and drivable (diana_lab.shield.site_map; needs detour_after > 0 or
    # route); 0: no site map
    site_map_cell: float = 0.0
    # depth cameras that feed only the shield's map (ShieldCameraConfig); []: the env sensor's returns alone
    cameras: list[ShieldCameraConfig] = field(default_factory=list)

    def __post_init__(self) -> None:
        non_negative_int("eval.shield.detour_after", self.detour_after, "0: off")
        in_range("eval.shield.relief_slope_deg", self.relief_slope_deg, 0.0, 90.0, inclusive=False)
        positive("eval.shield.relief_step", self.relief_step)
        positive("eval.shield.relief_roughness", self.relief_roughness)
        non_negative("eval.shield.relief_unseen_from", self.relief_unseen_from)
        if self.relief_unseen_from > 0 and not self.relief:
            raise ConfigError(
                f"eval.shield.relief_unseen_from={self.relief_unseen_from}: expected eval.shield.relief=true with it "
                "(the cells it keeps off are those the relief check cannot judge), or 0"
            )
        if isinstance(self.relief_min_known, bool) or not isinstance(self.relief_min_known, int):
            raise ConfigError(f"eval.shield.relief_min_known: expected an integer >= 3, got {self.relief_min_known!r}")
        if self.relief_min_known < 3:
            raise ConfigError(
                f"eval.shield.relief_min_known: expected an integer >= 3 (a plane needs 3), got {self.relief_min_known}"
            )
        for i, camera in enumerate(self.cameras):
            if not isinstance(camera, ShieldCameraConfig):
                raise ConfigError(
                    f"eval.shield.cameras[{i}]: expected a camera (yaw_deg, mount_xyz, pitch_deg, width, height, "
                    f"hfov_deg, vfov_deg, max_range), got {camera!r}"
                )
            camera.check(f"eval.shield.cameras[{i}]")
        if not isinstance(self.route, bool):
            raise ConfigError(f"eval.shield.route: expected true or false, got {self.route!r}")
        non_negative("eval.shield.route_tolerance", self.route_tolerance)
        non_negative("eval.shield.site_map_cell", self.site_map_cell)
        if self.site_map_cell > 0 and not (self.detour_after > 0 or self.route):
            raise ConfigError(
                f"eval.shield.site_map_cell={self.site_map_cell}: the site map is read by the shield's search, which "
                "runs only with eval.shield.detour_after > 0 or eval.shield.route=true; set one, or 0 for no site map"
            )
        non_negative("eval.shield.slope_cost_weight", self.slope_cost_weight)
        in_range("eval.shield.slope_cost_from_deg", self.slope_cost_from_deg, 0.0, 90.0, inclusive=False)
        in_range("eval.shield.slope_cost_to_deg", self.slope_cost_to_deg, 0.0, 90.0, inclusive=False)
        if not self.slope_cost_from_deg < self.slope_cost_to_deg:
            raise ConfigError(
                f"eval.shield.slope_cost_to_deg: expected more than eval.shield.slope_cost_from_deg "
                f"({self.slope_cost_from_deg}), got {self.slope_cost_to_deg}"
            )
        positive("eval.shield.detour_progress", self.detour_progress)
        positive("eval.shield.detour_margin", self.detour_margin)
        non_negative("eval.shield.smooth_roughness", self.smooth_roughness)
        non_negative("eval.shield.smooth_obstacle_height", self.smooth_obstacle_height)
        positive("eval.shield.smooth_radius", self.smooth_radius)
        if self.smooth_roughness > 0 and not 0 < self.smooth_obstacle_height < self.obstacle_height:
            raise ConfigError(
                "eval.shield.smooth_obstacle_height: with eval.shield.smooth_roughness > 0, expected a height above "
                f"0 and below eval.shield.obstacle_height ({self.obstacle_height}), got {self.smooth_obstacle_height}"
            )
        non_negative("eval.shield.approach_radius", self.approach_radius)
        positive("eval.shield.approach_tolerance", self.approach_tolerance)
        non_negative("eval.shield.min_range", self.min_range)
        non_negative("eval.shield.revisit_radius", self.revisit_radius)
        non_negative("eval.shield.peak_height", self.peak_height)
        for key, value, lo in (("peak_rank", self.peak_rank, 0), ("peak_min_known", self.peak_min_known, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= 8:
                raise ConfigError(f"eval.shield.{key}: expected an integer in {lo}..8, got {value!r}")
        non_negative("eval.shield.hazard_radius", self.hazard_radius)
        non_negative("eval.shield.obstacle_height", self.obstacle_height)
        positive("eval.shield.cell_size", self.cell_size)
        positive("eval.shield.spacing", self.spacing)
        positive("eval.shield.radius", self.radius)
        in_range("eval.shield.limit_deg", self.limit_deg, 0.0, 90.0, inclusive=False)
        positive_int("eval.shield.top_k", self.top_k)


@dataclass
class EvalConfig:
    """How a policy is evaluated (``python -m diana_lab.evaluate`` and the training runner's evaluations)."""

    episodes: int = 100  # episodes in the suite
    seed: int = 12345  # the suite's own seed (starts, goals, headings and per-episode noise seeds)
    min_distance: float = 8.0  # start-goal straight-line distance range (m)
    max_distance: float = 30.0
    # m/s: a successful episode slower than this (goal-directed: straight-line distance over time) counts in the
    # summary's slow_successes; the paper's minimum, a quarter of its rover's 0.33 m/s cruise
    min_goal_speed: float = 0.083
    every: int = 10000  # training steps between periodic evaluations (the runner); 0 disables them
    deterministic: bool = True  # RL policies act with their mean/mode action
    dynamics: str | None = None  # None: the same dynamics as training; else "kinematic" or "physics"
    sensor_noise: list[float] = field(default_factory=list)  # noise levels to sweep; []: the configured sensor
    video: bool = True  # a GIF of the first episode
    plots: bool = True  # trajectory and tilt plots
    shield: ShieldConfig = field(default_factory=ShieldConfig)  # a slope check on learnt discrete policies

    def __post_init__(self) -> None:
        positive_int("eval.episodes", self.episodes)
        check_seed("eval.seed", self.seed)
        non_negative_int("eval.every", self.every, "0 disables")
        non_negative("eval.min_distance", self.min_distance)
        ordered("eval.min_distance", self.min_distance, "eval.max_distance", self.max_distance)
        non_negative("eval.min_goal_speed", self.min_goal_speed)
        if self.dynamics is not None:
            one_of("eval.dynamics", self.dynamics, DYNAMICS_OPTIONS)
        for i, level in enumerate(self.sensor_noise):
            non_negative(f"eval.sensor_noise[{i}]", level)


register("eval", {"eval": EvalConfig})
