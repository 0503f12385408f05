"""A slope shield: the rover's own height map vetoes a candidate waypoint whose straight drive looks too steep.

Why it exists: a learnt policy choosing among candidate waypoints picks near-tied candidates, some of them into
ground it could have seen was too steep; checking the chosen drive on a finer map of the same returns before it is
driven is what a rover's onboard safety layer does ("shielding" a learnt policy). What each rule bought was measured
on validation suites: docs/reference_policy.md.

The checks and rules (numpy only, so the onboard runtime shares them):

* tilt: along the straight drive, every ``spacing`` metres, the map's heights under the axles (pitch) and the tracks
  (roll); a drive whose tilt passes ``limit_deg`` is vetoed (unseen ground passes). The first allowed of the policy's
  ``top_k`` most probable candidates is driven;
* fallback: when none is allowed, the tilt check is dropped and the others kept; only if none is left then is the
  policy's own choice driven (a rover on a steep rim would otherwise repeat the drive that halted);
* hazards felt (``hazard_radius``): no drive near where the wheels met ground they could not drive this episode
  (the tilt guard's trip, a slope that held them): the wheels feel what the map misses;
* obstacles (``obstacle_height``, lower on smooth ground with ``smooth_roughness``) and peaks (``peak_height``): no
  drive whose footprint holds something standing over its wheel probes or over its neighbours' cells (a rock);
* places stood on (``revisit_radius``): among the allowed, the first ending away from every earlier position (a
  tabu list: the policy does not know where it has been, and loops were the yard's failures);
* the rules of ``rules`` (:mod:`diana_lab.shield.rules`), asked first in their order: final approach
  (``approach_radius``), detour (``detour_after``, :mod:`diana_lab.shield.detour`) and route rule (``route``):
  near the goal, when stalled, and at every decision, drives chosen by a search over this map;
* relief (``relief``): no drive across cells whose footprint is steep, stepped or rough on the map's mean returns,
  or (``relief_unseen_from``) across ground it cannot judge (:mod:`diana_lab.shield.relief`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from diana_lab.core.height_memory import HeightMemory
from diana_lab.core.rotations import level_points
from diana_lab.shield.detour import Detour
from diana_lab.shield.relief import ReliefLimits, relief_judgement
from diana_lab.shield.rules import RULES, Decision
from diana_lab.shield.settings import ShieldSettings
from diana_lab.shield.site_map import SiteMap

__all__ = ["VETO_CHECKS", "ShieldSettings", "SlopeShield"]

# the relief check: the points of a drive it is judged at (as shares of its length)
RELIEF_SAMPLES = 30
RELIEF_ALONG = np.linspace(0.05, 1.0, RELIEF_SAMPLES)

# the checks a veto of the policy's own choice is put down to (:attr:`SlopeShield.vetoed_by`), in report order;
# ``place``: the place rule (allowed, but it ended where the rover had stood: ``revisits``)
# ``smooth``: a rise over the smooth-ground limit but not over ``obstacle_height``
# ``relief``: the drive crosses a cell the relief check calls a hazard (``relief``; diana_lab.shield.relief)
VETO_CHECKS = ("tilt", "relief", "hazard", "obstacle", "smooth", "peak", "place")


def closest_approach(offsets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """How near each straight drive ``offsets`` ``(K, 2)`` from the rover comes to each of ``points`` ``(P, 2)``
    (both relative to the rover), ``(K, P)`` metres."""
    sq = np.maximum((offsets * offsets).sum(axis=1), 1e-18)[:, None]  # (K, 1)
    t = np.clip((offsets @ points.T) / sq, 0.0, 1.0)  # (K, P): where along each drive it comes closest
    gap = t[..., None] * offsets[:, None, :] - points[None]
    return np.hypot(gap[..., 0], gap[..., 1])


class SlopeShield:
    """See the module docstring. ``observe`` every frame, ``choose`` per decision, ``reset`` per episode
    (a new goal onboard)."""

    def __init__(self, settings: ShieldSettings) -> None:  # settings checked when built (ShieldSettings)
        self.relief: ReliefLimits | None = settings.relief_limits()
        # the detour's search, which the route rule uses too (its stall count only with detour_after > 0)
        self.detour = (
            Detour(
                max(settings.detour_after, 1),
                settings.detour_progress,
                settings.detour_margin,
                settings.limit_deg,
                settings.hazard_radius,
                pool=max(1, round(2.0 * settings.half_track / settings.cell_size)),  # the track width in cells
                relief=self.relief,
                slope_cost=settings.slope_cost(),
            )
            if settings.detour_after > 0 or settings.route
            else None
        )
        self._smooth_reach = max(1, round(settings.smooth_radius / (2.0 * settings.cell_size)))  # in 2 x 2 blocks
        self._smooth_at: tuple[float, float, bool] | None = None  # (x, y, smooth) since the map last changed
        # the obstacle check's probes around each sample: the centre and rings at half and the whole footprint
        ring = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
        unit = np.stack([np.cos(ring), np.sin(ring)], axis=1)
        r = settings.footprint_radius
        self._footprint = np.concatenate([np.zeros((1, 2)), 0.5 * r * unit[::2], r * unit])  # (13, 2)
        self.cfg = settings
        self._footprint_checks = settings.obstacle_height > 0 or settings.peak_height > 0
        self.memory = HeightMemory(settings.cell_size, settings.radius, 1, 1, 0.0, 0.0, mean=settings.relief)
        # (x, y, reach, ix0, iy0, hazard, judged) of the relief grid round the rover, since the map last changed
        self._relief_at: tuple[float, float, float, int, int, np.ndarray, np.ndarray] | None = None
        self._samples: dict[float, np.ndarray] = {}  # distances along a drive, per drive length
        self.half_base, self.half_track = settings.half_base, settings.half_track
        self.decisions = 0  # calls of choose() since construction
        self.vetoes = 0  # of which drove another candidate than the policy's first
        self.revisits = 0  # of which the place rule alone turned from the first allowed candidate
        self.fallbacks = 0  # decisions that found no candidate allowed (the tilt check dropped, see _fallback)
        self.approaches = 0  # decisions the final approach made (the goal within approach_radius, its drive allowed)
        self.detours = 0  # decisions the detour made (no progress for detour_after decisions; diana_lab.shield.detour)
        self.routes = 0  # decisions the route rule turned from the policy's choice (``route``; diana_lab.shield.detour)
        # of the vetoes, how many each check made: every check the policy's own choice failed counts (one veto
        # can fail several, so the counts can sum past ``vetoes``); a choice that failed none was driven
        self.vetoed_by = dict.fromkeys(VETO_CHECKS, 0)
        self.hazards = np.zeros((0, 2))  # this episode's hazards felt (world xy)
        self._stood = np.zeros((0, 2))  # where the rover stood at this episode's decisions (world xy), each once

    def reset(self) -> None:
        """A new episode: forget the map, the hazards and the places stood on (the counters keep running over
        the suite)."""
        self.memory.reset()
        self._smooth_at = None
        self._relief_at = None
        if self.detour is not None:
            self.detour.reset()
        self.hazards = np.zeros((0, 2))
        self._stood = np.zeros((0, 2))

    def use_site_map(self, site_map: SiteMap | None) -> None:
        """Let the search (the detour's and the route rule's) read ``site_map`` where this map gives no slope
        (:mod:`diana_lab.shield.site_map`; None: unseen ground is drivable again). Kept across :meth:`reset`: it
        is the site's, not the traverse's."""
        if site_map is not None and self.detour is None:
            raise ValueError(
                "SlopeShield.use_site_map: this shield has no search to read a site map (its settings have "
                "detour_after 0 and route false)"
            )
        if self.detour is not None:
            self.detour.site_map = site_map

    def mark_hazard(self, xy: Sequence[float] | None) -> None:
        """Remember where the wheels met ground they could not drive (``None``: nothing to remember); kept only
        with ``hazard_radius`` > 0."""
        if xy is not None and self.cfg.hazard_radius > 0:
            point = np.asarray(xy, dtype=np.float64).reshape(1, 2)
            self.hazards = np.concatenate([self.hazards, point])

    def near_hazard(self, start_xy: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Whether each straight drive in ``offsets`` ``(K, 2)`` comes within ``hazard_radius`` of a hazard felt
        this episode, ``(K,)`` bool (the segment's closest approach). A rover already that close (a slope held it
        just short of the spot) may drive anywhere that does not take it closer than it is."""
        offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 2)
        if len(self.hazards) == 0 or len(offsets) == 0:
            return np.zeros(len(offsets), dtype=bool)
        rel = self.hazards - np.asarray(start_xy, dtype=np.float64)[:2]  # (H, 2)
        closest = closest_approach(offsets, rel)
        reach = np.minimum(np.hypot(rel[:, 0], rel[:, 1]), self.cfg.hazard_radius)
        return (closest < reach).any(axis=1)

    def relief_crosses(self, start_xy: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Whether each straight drive in ``offsets`` ``(K, 2)`` from ``start_xy`` crosses a cell the relief check
        calls a hazard (:mod:`diana_lab.shield.relief`, on the map's mean layer), or, with ``relief_unseen_from`` > 0, a
        cell it cannot judge (unseen ground, or too little of its footprint seen) more than that far along it,
        ``(K,)`` bool; all False with the check off. Judged at :data:`RELIEF_SAMPLES` points from 5 % of the way
        to its end (the rover's own cell is where it stands: a hazard there would veto every drive), on one grid
        round the rover per decision (kept until the map changes or the rover moves, and widened only when a
        longer drive needs it); ground beyond the map is unjudged."""
        offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 2)
        if self.relief is None or self.memory.origin is None or len(offsets) == 0:
            return np.zeros(len(offsets), dtype=bool)
        start = np.asarray(start_xy, dtype=np.float64)[:2]
        mem, c = self.memory, self.memory.cell_size
        lengths = np.sqrt((offsets * offsets).sum(axis=1))
        reach = float(lengths.max()) + c
        cached = self._relief_at
        same_start = cached is not None and cached[:2] == (start[0], start[1])
        if not same_start or cached[2] < reach:  # one grid a decision, grown only for a longer drive
            if same_start:
                reach = max(reach, cached[2])
            lo = np.floor((start - reach - mem.origin) / c).astype(int)
            hi = np.ceil((start + reach - mem.origin) / c).astype(int)
            ix0, iy0 = max(0, int(lo[0])), max(0, int(lo[1]))
            ix1, iy1 = min(mem.n, int(hi[0])), min(mem.n, int(hi[1]))
            assert mem.mean_height is not None  # built with mean=True whenever the relief check is on
            hazard, judged = relief_judgement(
                mem.mean_height.reshape(mem.n, mem.n), (ix0, iy0, ix1, iy1), c, self.relief
            )
            cached = self._relief_at = (start[0], start[1], reach, ix0, iy0, hazard, judged)
        ix0, iy0, hazard, judged = cached[3], cached[4], cached[5], cached[6]
        points = start + RELIEF_ALONG[None, :, None] * offsets[:, None, :]  # (K, S, 2)
        fx = np.floor((points[..., 0] - mem.origin[0]) / c).astype(np.int64) - ix0
        fy = np.floor((points[..., 1] - mem.origin[1]) / c).astype(np.int64) - iy0
        ny, nx = hazard.shape
        inside = (fx >= 0) & (fx < nx) & (fy >= 0) & (fy < ny)
        if hazard.size == 0:
            cells_hazard, cells_judged = np.zeros(fx.shape, dtype=bool), np.zeros(fx.shape, dtype=bool)
        else:
            at = (np.clip(fy, 0, ny - 1), np.clip(fx, 0, nx - 1))
            cells_hazard, cells_judged = inside & hazard[at], inside & judged[at]
        crosses = cells_hazard.any(axis=1)
        unseen_from = self.cfg.relief_unseen_from
        if unseen_from > 0:
            beyond = RELIEF_ALONG[None, :] * lengths[:, None] >= unseen_from
            crosses |= (beyond & ~cells_judged).any(axis=1)
        return crosses

    def observe(self, points_world: np.ndarray, rover_xy: np.ndarray) -> None:
        """Fuse one frame's returns, ``(N, 3)`` in the world frame; ``rover_xy`` centres the map on an
        episode's first frame."""
        self.memory.update(np.asarray(points_world, dtype=np.float32).reshape(-1, 3), rover_xy)
        self._smooth_at = None
        self._relief_at = None

    def observe_rover(
        self,
        points_rover: np.ndarray,
        position: Sequence[float],
        rpy: Sequence[float],
        sensor_xyz: Sequence[float] | None = None,
    ) -> None:
        """:meth:`observe` of returns in the rover frame, ``(N, 3)``, taken at world ``position`` and attitude
        ``rpy``: levelled and placed as the ``elevation_map`` memory places them (simulator and onboard alike).
        With ``min_range`` > 0, returns nearer than that to the sensor (at ``sensor_xyz`` in the rover frame,
        required then) are left out."""
        pts = np.asarray(points_rover, dtype=np.float32).reshape(-1, 3)
        if self.cfg.min_range > 0:
            pts = self.far_points(pts, pts, sensor_xyz)
        levelled = level_points(pts, float(rpy[0]), float(rpy[1]))
        self.observe(HeightMemory.to_world(levelled, position, float(rpy[2])), np.asarray(position)[:2])

    def far_points(
        self, points: np.ndarray, points_rover: np.ndarray, sensor_xyz: Sequence[float] | None
    ) -> np.ndarray:
        """The rows of ``points`` (any frame) whose returns ``points_rover`` (the same, rover frame) are
        :meth:`far_enough`: ``points[far_enough(...)]``, but ``points`` itself when every return is (the usual
        case: a boolean row selection costs more than the test) and a ``take`` otherwise."""
        keep = self.far_enough(points_rover, sensor_xyz)
        return points if keep.all() else points.take(np.flatnonzero(keep), axis=0)

    def far_enough(self, points_rover: np.ndarray, sensor_xyz: Sequence[float] | None) -> np.ndarray:
        """Which returns (rover frame, ``(N, 3)`` float32) lie at least ``min_range`` from the sensor at
        ``sensor_xyz`` (rover frame): the ones the map keeps."""
        if sensor_xyz is None:
            raise ValueError("SlopeShield: min_range > 0 needs the sensor's position (sensor_xyz)")
        sx, sy, sz = np.asarray(sensor_xyz, dtype=np.float32)
        # by column: numpy's (N, 3) broadcasts and row sums loop 3 wide and cost ~10x more (the same sums)
        x, y, z = points_rover[:, 0] - sx, points_rover[:, 1] - sy, points_rover[:, 2] - sz
        return x * x + y * y + z * z >= np.float32(self.cfg.min_range) ** 2

    def steepest_deg(self, start_xy: np.ndarray, offset: np.ndarray) -> float:
        """The largest pitch or roll (degrees) the map shows along the straight drive from ``start_xy`` by
        ``offset`` (world frame); 0 where it knows nothing of the way."""
        return float(self.steepest_many(start_xy, np.asarray(offset, dtype=np.float64).reshape(1, 2))[0])

    def steepest_many(self, start_xy: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """:meth:`steepest_deg` of every drive in ``offsets`` ``(K, 2)``, ``(K,)``: one map lookup for all of
        them, so a decision costs the same whether the policy's first choice passes or its 16th."""
        start = np.asarray(start_xy, dtype=np.float64)[:2]
        offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 2)
        if len(offsets) == 1:  # the common call (the policy's own choice): fewer, smaller steps
            return np.array([self._steepest_one(start, offsets[0])])
        lengths = np.hypot(offsets[:, 0], offsets[:, 1])
        moving = lengths >= 1e-9
        # np.arange(0, length + 1e-9, spacing) per drive, all drives in one flat array
        counts = np.where(moving, np.ceil((lengths + 1e-9) / self.cfg.spacing).astype(np.int64), 0)
        owner = np.repeat(np.arange(len(offsets)), counts)
        first = np.cumsum(counts) - counts
        s = (np.arange(int(counts.sum())) - np.repeat(first, counts)) * self.cfg.spacing
        u = offsets[owner] / np.where(moving, lengths, 1.0)[owner, None]
        n = np.stack([-u[:, 1], u[:, 0]], axis=1)
        tilt = self._sample_tilts(start + s[:, None] * u, u, n)
        worst = np.zeros(len(offsets))
        np.fmax.at(worst, owner, np.nan_to_num(tilt, nan=0.0))  # NaN (unknown) counts as level
        return np.degrees(np.arctan(worst))

    def _steepest_one(self, start: np.ndarray, offset: np.ndarray) -> float:
        """:meth:`steepest_many` of one drive, with the same probes to the bit."""
        return float(np.degrees(np.arctan(self._probe_one(start, offset, obstacles=False)[0])))

    def _probe_one(self, start: np.ndarray, offset: np.ndarray, obstacles: bool) -> tuple[float, float, float]:
        """One drive's steepest tilt (a tangent, :meth:`_sample_tilts`' largest; 0 where nothing is known) and,
        with ``obstacles``, what rises above the wheels (:meth:`obstacle_m`) and the highest peak in the footprint
        (:meth:`peak_m`, with ``peak_height`` > 0), from one map lookup: the wheel probes at every sample serve
        the checks (a decision is timed onboard; the lookup is most of it)."""
        length = float(np.hypot(offset[0], offset[1]))
        if length < 1e-9:
            return 0.0, 0.0, 0.0
        s = self._samples.get(length)
        if s is None:
            s = self._samples[length] = np.arange(0.0, length + 1e-9, self.cfg.spacing)[:, None]
        u = np.asarray(offset, dtype=np.float64) / length
        centre = start + s * u
        probes = self._wheel_probes(centre, u, np.array([-u[1], u[0]]))
        m = len(centre)
        if obstacles:  # the footprint around every sample but the rover's own place
            around = (centre[1:, None, :] + self._footprint[None]).reshape(-1, 2)
            probes = np.concatenate([probes, around])
        h, _ = self.memory.heights_at(probes[:, 0], probes[:, 1])
        wheels = h[: 4 * m].reshape(4, m)
        worst = float(np.fmax.reduce(self._tilts(wheels), initial=0.0))  # NaN (unknown) drops out; all unknown: 0
        if not obstacles or m < 2:
            return worst, 0.0, 0.0
        with np.errstate(invalid="ignore"):
            ground = np.fmax.reduce(wheels[:, 1:], axis=0)  # NaN only where no wheel probe is known
            top = np.fmax.reduce(h[4 * m :].reshape(m - 1, -1), axis=1)
            rise = float(np.fmax.reduce(top - ground, initial=0.0))
        peak = 0.0
        if self.cfg.peak_height > 0:
            ring = probes[4 * m :]
            peaks = self.memory.peaks_at(ring[:, 0], ring[:, 1], self.cfg.peak_min_known, self.cfg.peak_rank)
            peak = float(peaks.max(initial=0.0))
        return worst, rise, peak

    def _sample_tilts(self, centre: np.ndarray, u: np.ndarray, n: np.ndarray) -> np.ndarray:
        """At each sample ``centre`` ``(m, 2)`` of a drive along ``u`` (``n`` to its left): the larger of the
        pitch over the wheelbase and the roll across the track the map shows, as a tangent; NaN where it
        knows neither."""
        probes = self._wheel_probes(centre, u, n)
        return self._tilts(self.memory.heights_at(probes[:, 0], probes[:, 1])[0].reshape(4, -1))

    def _tilts(self, wheels: np.ndarray) -> np.ndarray:
        """The map's heights under the wheel probes, ``(4, m)`` (:meth:`_wheel_probes`' order) -> the larger of the
        pitch over the wheelbase and the roll across the track at each sample, as a tangent; NaN where neither
        is known."""
        front, rear, left, right = wheels
        with np.errstate(invalid="ignore"):
            return np.fmax(
                np.abs(front - rear) / (2.0 * self.half_base), np.abs(left - right) / (2.0 * self.half_track)
            )

    def obstacle_m(self, start_xy: np.ndarray, offset: np.ndarray) -> float:
        """The most the map shows anything within the rover's footprint rising above its highest wheel probe
        (front and rear axle centres, left and right tracks) along the straight drive, every ``spacing`` m
        after the start (m; 0 where it knows nothing): a rock between or beside the wheels that the tilt check
        cannot see. 0 with the check off."""
        if self.cfg.obstacle_height <= 0:
            return 0.0
        return self._probe_one(np.asarray(start_xy, dtype=np.float64)[:2], offset, obstacles=True)[1]

    def peak_m(self, start_xy: np.ndarray, offset: np.ndarray) -> float:
        """The most a cell of the map within the rover's footprint stands above its neighbours (their median, or
        their ``peak_rank``-th highest) along the straight drive (:meth:`HeightMemory.peaks_at`, every ``spacing`` m
        after the start; m, 0 where nothing is judged): a rock, which the obstacle check misses when one of its
        wheel probes, its reference, lies on the rock's own smeared cells. 0 with the check off."""
        if self.cfg.peak_height <= 0:
            return 0.0
        return self._probe_one(np.asarray(start_xy, dtype=np.float64)[:2], offset, obstacles=True)[2]

    def _wheel_probes(self, centre: np.ndarray, u: np.ndarray, n: np.ndarray) -> np.ndarray:
        """The front and rear axle centres and the left and right tracks at every sample ``centre`` ``(m, 2)`` of
        a drive along ``u`` (``n`` to its left): ``(4 m, 2)``, in that order."""
        along, across = self.half_base * u, self.half_track * n
        return np.concatenate([centre + along, centre - along, centre + across, centre - across])

    def allows(self, start_xy: np.ndarray, offset: np.ndarray) -> bool:
        """Whether the drive is not vetoed (:meth:`steepest_deg` at most ``limit_deg``, not near a hazard felt,
        and no obstacle in the footprint above ``obstacle_height`` nor peak above ``peak_height``): one map
        lookup for all the map checks."""
        return not self.failed_checks(start_xy, offset)

    def failed_checks(self, start_xy: np.ndarray, offset: np.ndarray) -> tuple[str, ...]:
        """The map checks the drive fails, of ``tilt``, ``hazard``, ``obstacle`` (or ``smooth``) and ``peak``
        (:data:`VETO_CHECKS`' order; empty: :meth:`allows` it), from the same single map lookup."""
        start = np.asarray(start_xy, dtype=np.float64)[:2]
        tilt, rise, peak = self._probe_one(start, np.asarray(offset, dtype=np.float64), self._footprint_checks)
        steep = ("tilt",) if float(np.degrees(np.arctan(tilt))) > self.cfg.limit_deg else ()
        relief = ("relief",) if self.relief_crosses(start, offset)[0] else ()
        near = ("hazard",) if self.near_hazard(start, offset)[0] else ()
        return steep + relief + near + self._footprint_failures(rise, peak, start)

    def _footprint_failures(self, rise: float, peak: float, start: np.ndarray) -> tuple[str, ...]:
        """``obstacle`` (or ``smooth``) and / or ``peak``, for a drive from ``start`` whose footprint rises
        ``rise`` above its wheels and holds a cell ``peak`` over its neighbours (:meth:`_probe_one`), as far as
        those checks are on."""
        cfg = self.cfg
        obstacle: tuple[str, ...] = ()
        if cfg.obstacle_height > 0 and rise > cfg.obstacle_height:
            obstacle = ("obstacle",)
        elif cfg.smooth_roughness > 0 and rise > cfg.smooth_obstacle_height and self.smooth_ground(start):
            obstacle = ("smooth",)
        return obstacle + (("peak",) if cfg.peak_height > 0 and peak > cfg.peak_height else ())

    def smooth_ground(self, start_xy: np.ndarray) -> bool:
        """Whether the map shows the ground within ``smooth_radius`` of ``start_xy`` smoother than
        ``smooth_roughness`` (:meth:`HeightMemory.roughness_near`; False with too little of it known or the rule
        off). Kept until the map or the place changes: a decision asks it for many candidates."""
        if self.cfg.smooth_roughness <= 0:
            return False
        x, y = float(start_xy[0]), float(start_xy[1])
        if self._smooth_at is None or self._smooth_at[:2] != (x, y):
            roughness = self.memory.roughness_near(x, y, self._smooth_reach)
            self._smooth_at = (x, y, bool(roughness < self.cfg.smooth_roughness))  # NaN: not smooth
        return self._smooth_at[2]

    def obstructed(self, start_xy: np.ndarray, offset: np.ndarray) -> bool:
        """Whether the footprint checks (obstacle, smooth ground, peak) veto the drive: the dearer part of
        :meth:`allows`, asked only of drives that pass the tilt and hazard checks."""
        if not self._footprint_checks:
            return False
        start = np.asarray(start_xy, dtype=np.float64)[:2]
        _, rise, peak = self._probe_one(start, offset, obstacles=True)
        return bool(self._footprint_failures(rise, peak, start))

    def fresh(self, start_xy: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Whether each drive in ``offsets`` ``(K, 2)`` ends at least ``revisit_radius`` from every place the
        rover stood at an earlier decision of this episode, ``(K,)`` bool (all True with the rule off)."""
        offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 2)
        if self.cfg.revisit_radius <= 0 or len(self._stood) == 0:
            return np.ones(len(offsets), dtype=bool)
        ends = np.asarray(start_xy, dtype=np.float64)[:2] + offsets
        dx = ends[:, 0, None] - self._stood[None, :, 0]
        dy = ends[:, 1, None] - self._stood[None, :, 1]
        return (dx * dx + dy * dy).min(axis=1) >= self.cfg.revisit_radius**2

    def choose(
        self,
        ranked: Sequence[int],
        offsets: np.ndarray,
        start_xy: np.ndarray,
        goal_xy: Sequence[float] | None = None,
    ) -> int:
        """The first of ``ranked`` (candidate indices, the policy's choice first) among its first ``top_k``
        whose drive ``offsets[k]`` (world frame, ``(n, 2)``) is allowed and, with ``revisit_radius``, ends away
        from the places stood on (else the first allowed); if none is allowed, :meth:`_fallback`'s. Before that,
        the rules named in ``rules`` (:mod:`diana_lab.shield.rules`: the final approach, the detour, the route
        rule), in their order, may decide; those that need the goal (world ``goal_xy``) pass without it."""
        if len(ranked) == 0:
            raise ValueError("SlopeShield.choose: expected at least one ranked candidate, got none")
        self.decisions += 1
        start = np.asarray(start_xy, dtype=np.float64)[:2]
        top = np.asarray(ranked, dtype=np.int64)[: self.cfg.top_k]
        offsets = np.asarray(offsets)
        fresh = self.fresh(start, offsets[top])
        if self.cfg.revisit_radius > 0 and not (len(self._stood) and (self._stood[-1] == start).all()):
            self._stood = np.concatenate([self._stood, start[None]])  # a rover that has not moved adds nothing
        goal = None if goal_xy is None else np.asarray(goal_xy, dtype=np.float64)[:2]
        # the stall count moves at every decision, whichever rule is asked first
        stalled = self.cfg.detour_after > 0 and goal is not None and self.detour.stalled(start, goal)
        decision = Decision(offsets[top], start, goal, fresh, stalled)
        for name in self.cfg.rules:
            j = RULES[name](self, decision)
            if j is not None:
                return int(top[j])
        # the policy's own choice first (the common case), then the rest at once
        first_failed = self.failed_checks(start, offsets[top[0]])
        first_allowed = not first_failed
        if first_allowed and fresh[0]:
            return int(top[0])
        rest = offsets[top[1:]]
        ok = (
            (self.steepest_many(start, rest) <= self.cfg.limit_deg)
            & ~self.near_hazard(start, rest)
            & ~self.relief_crosses(start, rest)
        )
        # the obstacle check costs more a drive: only for the candidates that pass the rest, in the policy's order
        allowed_first = 0 if first_allowed else None  # the first allowed (as an index into top)
        pick = None
        for j in np.flatnonzero(ok):
            if allowed_first is not None and not fresh[1 + j]:
                continue  # only a fresh candidate can still change the choice
            if self.obstructed(start, rest[j]):
                continue
            if fresh[1 + j]:
                pick = 1 + j
                break
            allowed_first = 1 + j
        if pick is None:
            pick = allowed_first
        elif allowed_first is not None:  # a fresh candidate after the first allowed: the place rule chose it
            self.revisits += 1
        if pick is None:
            self.fallbacks += 1
            pick = self._fallback(start, offsets[top], fresh)
        if pick == 0:
            return int(top[0])
        self.vetoes += 1
        for name in first_failed or ("place",):  # allowed, so the place rule turned from it
            self.vetoed_by[name] += 1
        return int(top[pick])

    def approach(self, offsets: np.ndarray, start_xy: np.ndarray, goal_xy: Sequence[float]) -> int | None:
        """The final approach: with the goal within ``approach_radius`` of ``start_xy``, the index into
        ``offsets`` ``(K, 2)`` (world frame; :meth:`choose` passes its ``top_k``) of the shortest drive passing
        within ``approach_tolerance`` of it (none does: the one passing nearest), if the checks allow it (the
        place rule does not apply: the goal ends the loop); else None. Why: the policy's candidates are ranked for
        the way, not for the goal itself; a rover drives the last metres straight when its checks allow them."""
        offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 2)
        g = np.asarray(goal_xy, dtype=np.float64)[:2] - np.asarray(start_xy, dtype=np.float64)[:2]
        if len(offsets) == 0 or math.hypot(g[0], g[1]) > self.cfg.approach_radius:
            return None
        closest = closest_approach(offsets, g[None])[:, 0]
        passing = np.flatnonzero(closest <= max(self.cfg.approach_tolerance, float(closest.min())))
        length = np.round(np.hypot(offsets[passing, 0], offsets[passing, 1]), 6)  # micrometres: one ring ties
        j = int(passing[np.lexsort((closest[passing], length))[0]])  # the shortest; then the nearest
        return j if self.allows(start_xy, offsets[j]) else None

    def _fallback(self, start: np.ndarray, offsets: np.ndarray, fresh: np.ndarray) -> int:
        """No candidate of ``offsets`` (the top ``top_k``, policy order) is allowed: the index of the first not
        near a hazard felt and not obstructed, one that ends away from the places stood on (``fresh``) first;
        0 (the policy's choice) if every one is. The tilt check (and the relief check with it) alone is dropped: on
        steep ground it vetoes every drive, and the one that halted is the worst to repeat (see the module
        docstring)."""
        first = None
        for j in np.flatnonzero(~self.near_hazard(start, offsets)):
            if self.obstructed(start, offsets[j]):
                continue
            if fresh[j]:
                return int(j)
            if first is None:
                first = int(j)
        return 0 if first is None else first
