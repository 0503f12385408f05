"""Config schemas of the simulation groups: ``world``, ``robot``, ``dynamics`` (and the controller)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import PurePath
from typing import ClassVar

from omegaconf import MISSING

from diana_lab.core.validation import ConfigError, boolean, check_seed, in_range, non_negative, ordered, positive

# ----------------------------------------------------------------------------------------------- world


@dataclass
class WorldConfig:
    """Common world keys. ``_target_`` builds a :class:`diana_lab.sim.world.World`."""

    _target_: str = MISSING
    name: str = MISSING
    seed: int = 0  # procedural worlds only (PROCEDURAL); the others refuse another value than 0
    obstacle_resolution: float = 0.1
    PROCEDURAL: ClassVar[bool] = False  # drawn from world.seed

    def __post_init__(self) -> None:
        check_seed("world.seed", self.seed)
        if self.seed and not self.PROCEDURAL:  # it would change nothing, silently
            raise ConfigError(
                f"world.seed={self.seed}: world={self.name} is not procedural, so a seed changes nothing; "
                "leave it at 0 (world=hills and world=craters are drawn from it)"
            )
        positive("world.obstacle_resolution", self.obstacle_resolution)


@dataclass
class MarsYardConfig(WorldConfig):
    _target_: str = "diana_lab.sim.worlds.mars_yard"
    name: str = "mars_yard"


@dataclass
class FlatConfig(WorldConfig):
    _target_: str = "diana_lab.sim.worlds.flat"
    name: str = "flat"
    size_x: float = 40.0
    size_y: float = 40.0
    resolution: float = 0.25

    def __post_init__(self) -> None:
        super().__post_init__()
        positive("world.size_x", self.size_x)
        positive("world.size_y", self.size_y)
        positive("world.resolution", self.resolution)
        if self.resolution > min(self.size_x, self.size_y) / 2:
            raise ConfigError(f"world.resolution: expected at most half the world size, got {self.resolution}")


@dataclass
class HillsConfig(FlatConfig):
    PROCEDURAL: ClassVar[bool] = True
    _target_: str = "diana_lab.sim.worlds.hills"
    name: str = "hills"
    max_slope_deg: float = 8.0
    feature_size: float = 8.0
    amplitude: float = 1.5

    def __post_init__(self) -> None:
        super().__post_init__()
        in_range("world.max_slope_deg", self.max_slope_deg, 0.0, 10.0, inclusive=False)
        positive("world.feature_size", self.feature_size)
        positive("world.amplitude", self.amplitude)


@dataclass
class CratersConfig(FlatConfig):
    PROCEDURAL: ClassVar[bool] = True
    _target_: str = "diana_lab.sim.worlds.craters"
    name: str = "craters"
    size_x: float = 50.0
    size_y: float = 50.0
    resolution: float = 0.2
    n_craters: int = 6
    crater_radius: tuple[float, float] = (2.0, 6.0)
    dune_amplitude: float = 0.3
    dune_wavelength: float = 9.0
    rock_density: float = 0.02  # rocks per square metre
    rock_size: tuple[float, float] = (0.25, 0.8)  # rock diameter range in metres

    def __post_init__(self) -> None:
        super().__post_init__()
        non_negative("world.n_craters", self.n_craters)
        positive("world.crater_radius[0]", self.crater_radius[0])
        ordered("world.crater_radius[0]", self.crater_radius[0], "world.crater_radius[1]", self.crater_radius[1])
        non_negative("world.dune_amplitude", self.dune_amplitude)
        positive("world.dune_wavelength", self.dune_wavelength)
        in_range("world.rock_density", self.rock_density, 0.0, 1.0)
        positive("world.rock_size[0]", self.rock_size[0])
        ordered("world.rock_size[0]", self.rock_size[0], "world.rock_size[1]", self.rock_size[1])


def dem_size_missing(key: str, axis: str, why: str) -> str:
    """The refusal of a ``world=dem`` size that is left out and cannot be read from the file (``why``)."""
    return f"{key}: missing, and required for world=dem: the DEM's extent along {axis} in metres ({why})"


@dataclass
class DemConfig(WorldConfig):
    """The user's own elevation model (GeoTIFF/TIFF, PNG 8/16-bit, or .npy)."""

    _target_: str = "diana_lab.sim.worlds.dem"
    name: str = "dem"
    # required: ``help`` is what the refusal of a command line without it says (diana_lab.config.to_object)
    path: str = field(default=MISSING, metadata={"help": "the elevation file (GeoTIFF/TIFF, 8/16-bit PNG or .npy)"})
    # the extent in metres, first sample to last; null: read from a GeoTIFF's georeferencing (a .png, a .npy or
    # a TIFF without georeferencing needs both). Given for a GeoTIFF, each must agree with the file's within one
    # sample spacing, or the world is refused (diana_lab.sim.worlds.dem)
    size_x: float | None = None
    size_y: float | None = None
    height_scale: float = 1.0
    height_offset: float = 0.0
    obstacles: list[str] = field(default_factory=list)
    # cells without a height (a GeoTIFF's nodata value or mask, NaN): false refuses the file, naming how many
    # and where; true gives each the height of its nearest valid cell, with a warning naming how many
    fill_nodata: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        suffix = PurePath(self.path).suffix.lower()
        for key, axis, size in (("world.size_x", "x", self.size_x), ("world.size_y", "y", self.size_y)):
            if size is not None:
                positive(key, size)
            elif suffix in (".png", ".npy"):  # never georeferenced: refused now, not when the world is built
                raise ConfigError(dem_size_missing(key, axis, f"a {suffix} file has no georeferencing"))
        positive("world.height_scale", self.height_scale)
        boolean("world.fill_nodata", self.fill_nodata)


# ----------------------------------------------------------------------------------------------- robot


@dataclass
class RobotConfig:
    """A rover: its URDF, wheels, footprint, speeds and limits. Lengths in metres, angles in degrees."""

    name: str = MISSING
    urdf: str = MISSING  # "package:urdf/jackal.urdf" (diana_lab/assets) or "pybullet_data:husky/husky.urdf"
    wheel_joints_left: list[str] = field(default_factory=list)
    wheel_joints_right: list[str] = field(default_factory=list)
    wheel_radius: float = MISSING
    track_width: float = MISSING  # lateral distance between left and right wheel centres
    axle_x: list[float] = field(default_factory=list)  # wheel axle positions along the body x axis
    length: float = MISSING
    width: float = MISSING
    height: float = MISSING
    mass: float = MISSING
    cruise_speed: float = 0.33  # m/s (the paper's top rover speed)
    turn_speed: float = 0.8  # rad/s, turning in place
    max_wheel_torque: float = 20.0  # N m per wheel
    ground_clearance: float = 0.05
    max_step_height: float = 0.1  # tallest step the wheels climb
    max_slope_deg: float = 25.0  # steepest climbable slope
    tipover_deg: float = 40.0  # roll or pitch beyond this is a tip-over
    base_height: float = 0.1  # base link origin above the ground plane when standing on flat ground
    # tilt fault protection (None: off): a drive halts where the rover's measured tilt first passes this, and
    # the rover backs ``guard_retreat`` metres along its own track (never past the drive's start; tripped while
    # turning in place, straight back); the waypoint ends as ``halted``, and where the tilt passed the limit is
    # reported (``hazard_xy``)
    tilt_guard_deg: float | None = None
    guard_retreat: float = 1.2
    # how it backs off: it first stands still ``guard_pause_s`` seconds (the wheels hold, the body settles), then
    # reverses at ``guard_retreat_speed`` m/s (null: ``cruise_speed``). In physics, reversing at full speed the
    # instant the guard trips jerks a rover that is already past the guard closer to rolling over
    guard_pause_s: float = 0.0
    guard_retreat_speed: float | None = None

    def __post_init__(self) -> None:
        for key in (
            "wheel_radius",
            "track_width",
            "length",
            "width",
            "height",
            "mass",
            "cruise_speed",
            "turn_speed",
            "max_wheel_torque",
            "max_slope_deg",
            "tipover_deg",
        ):
            positive(f"robot.{key}", getattr(self, key))
        non_negative("robot.ground_clearance", self.ground_clearance)
        non_negative("robot.max_step_height", self.max_step_height)
        in_range("robot.cruise_speed", self.cruise_speed, 0.01, 3.0)
        in_range("robot.tipover_deg", self.tipover_deg, 1.0, 89.0)
        in_range("robot.max_slope_deg", self.max_slope_deg, 1.0, 89.0)
        if self.tilt_guard_deg is not None and not 0.0 < self.tilt_guard_deg < self.tipover_deg:
            raise ConfigError(
                f"robot.tilt_guard_deg: expected null (off) or an angle in (0, robot.tipover_deg = "
                f"{self.tipover_deg}) degrees, got {self.tilt_guard_deg}"
            )
        non_negative("robot.guard_retreat", self.guard_retreat)
        non_negative("robot.guard_pause_s", self.guard_pause_s)
        if self.guard_retreat_speed is not None:
            in_range("robot.guard_retreat_speed", self.guard_retreat_speed, 0.01, 3.0)
        if not self.wheel_joints_left or not self.wheel_joints_right:
            raise ConfigError("robot.wheel_joints_left / wheel_joints_right: expected at least one joint per side")
        if len(self.axle_x) < 2:
            raise ConfigError(f"robot.axle_x: expected at least two axle positions, got {list(self.axle_x)}")

    @property
    def radius(self) -> float:
        """Radius of the circle that encloses the footprint."""
        return 0.5 * (self.length**2 + self.width**2) ** 0.5

    @property
    def retreat_speed(self) -> float:
        """How fast the tilt guard backs the rover off (m/s): ``guard_retreat_speed``, else ``cruise_speed``."""
        return self.cruise_speed if self.guard_retreat_speed is None else self.guard_retreat_speed


# ----------------------------------------------------------------------------------------------- controller + dynamics


@dataclass
class ControllerConfig:
    """The paper's turn-then-drive position controller."""

    heading_tolerance_deg: float = 5.0  # turn in place until the heading error is below this
    position_tolerance: float = 0.2  # waypoint reached within this distance (m)
    steer_gain: float = 1.5  # heading correction while driving (rad/s per rad)
    timeout_factor: float = 2.5  # give up after this many times the nominal time ...
    timeout_margin: float = 5.0  # ... plus this many seconds
    rate_hz: float = 10.0  # control rate in physics mode

    def __post_init__(self) -> None:
        in_range("dynamics.controller.heading_tolerance_deg", self.heading_tolerance_deg, 0.1, 90.0)
        positive("dynamics.controller.position_tolerance", self.position_tolerance)
        non_negative("dynamics.controller.steer_gain", self.steer_gain)
        in_range("dynamics.controller.timeout_factor", self.timeout_factor, 1.0, 100.0)
        non_negative("dynamics.controller.timeout_margin", self.timeout_margin)
        positive("dynamics.controller.rate_hz", self.rate_hz)


@dataclass
class PoseNoiseConfig:
    """Noise of the pose estimate the agent and the controller see (zero: perfect localisation)."""

    position_std: float = 0.0  # m
    yaw_std_deg: float = 0.0
    tilt_std_deg: float = 0.0

    def __post_init__(self) -> None:
        non_negative("dynamics.pose_noise.position_std", self.position_std)
        non_negative("dynamics.pose_noise.yaw_std_deg", self.yaw_std_deg)
        non_negative("dynamics.pose_noise.tilt_std_deg", self.tilt_std_deg)


@dataclass
class DynamicsConfig:
    _target_: str = MISSING
    name: str = MISSING
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    pose_noise: PoseNoiseConfig = field(default_factory=PoseNoiseConfig)
    stuck_window_s: float = 6.0  # stuck: less than stuck_distance of progress within this window
    stuck_distance: float = 0.1


@dataclass
class KinematicConfig(DynamicsConfig):
    _target_: str = "diana_lab.sim.kinematic.KinematicDynamics"
    name: str = "kinematic"
    sample_spacing: float = 0.1  # m between terrain checks along the path
    # m the rover carries on past the tilt guard's trip while driving: a halt with the tip-over limit passed
    # within it is a tip-over (0: the guard stops the rover where it trips)
    guard_overshoot: float = 0.0

    def __post_init__(self) -> None:
        positive("dynamics.sample_spacing", self.sample_spacing)
        non_negative("dynamics.guard_overshoot", self.guard_overshoot)
        positive("dynamics.stuck_window_s", self.stuck_window_s)


@dataclass
class PhysicsConfig(DynamicsConfig):
    _target_: str = "diana_lab.sim.physics.PhysicsDynamics"
    name: str = "physics"
    time_step: float = 1.0 / 60.0
    solver_iterations: int = 10
    friction: float = 0.9
    settle_time_s: float = 1.0

    def __post_init__(self) -> None:
        in_range("dynamics.time_step", self.time_step, 1e-4, 0.05)
        positive("dynamics.solver_iterations", self.solver_iterations)
        positive("dynamics.friction", self.friction)
        non_negative("dynamics.settle_time_s", self.settle_time_s)
        positive("dynamics.stuck_window_s", self.stuck_window_s)
