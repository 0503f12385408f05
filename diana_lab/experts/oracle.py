"""The A* oracle baseline: plans over the whole map and hands its waypoints to the controller one by one.

Why it does not plan on the sampler's cost map as is: that map judges slope by a plane over the footprint's
enclosing disc, while the kinematic model stops the rover when the plane through the four wheel contacts pitches
past ``robot.max_slope_deg`` (steeper on rims and bumps), and its obstacle band is exactly the collision radius,
which shortcuts and heading drift graze. So the oracle, meant to know the map and the robot, adds a layer measured
the way the rover measures it -- the steepest chassis pitch over headings of the plane through the wheel contacts
(:func:`wheel_pitch_deg`), widened by a drift margin -- and a clearance margin round obstacles
(:func:`oracle_costmaps`):

* a soft cost growing quadratically near the slope limit and near obstacles (prefer safe ground), and
* a hard ban above the slope limit and within the clearance margin, with a fall-back to the soft map, then to the
  sampler's own map, when the ban disconnects start and goal.

All maps keep the sampler's untraversable cells, so the oracle never leaves the region the episode was drawn in.
The figures behind these choices: docs/implementation_notes.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
from scipy import ndimage as ndi

from diana_lab.config.sim import RobotConfig
from diana_lab.experts.actions import waypoint_action
from diana_lab.planning import CostMap, choose_waypoint, plan, simplify
from diana_lab.sim.world import World

__all__ = ["AStarOracle", "oracle_costmaps", "wheel_pitch_deg"]

HEADINGS = 8  # over [0, pi): the wheel set is symmetric under a half turn, so pitch(h + pi) = -pitch(h)


def wheel_pitch_deg(world: World, robot: RobotConfig, costmap: CostMap, headings: int = HEADINGS) -> np.ndarray:
    """For every cost-map cell, the steepest pitch (deg) over ``headings`` of the plane through the wheels.

    The plane is the least-squares fit ``z = a + b * bx + c * by`` through the terrain heights under the wheel
    contacts (axles ``robot.axle_x``, sides at ``+-track_width / 2``), the kinematic model's own pose rule.
    """
    ny, nx = costmap.shape
    cx, cy = costmap.cell_to_world(np.arange(nx), np.arange(ny))
    gx, gy = np.meshgrid(cx, cy)
    half = robot.track_width / 2.0
    wheels = np.array([(ax, side) for ax in robot.axle_x for side in (half, -half)])
    along = np.linalg.pinv(np.column_stack([np.ones(len(wheels)), wheels]))[1]  # weights giving b
    worst = np.zeros((ny, nx))
    for h in np.arange(headings) * math.pi / headings:
        c, s = math.cos(h), math.sin(h)
        wx = gx[..., None] + c * wheels[:, 0] - s * wheels[:, 1]
        wy = gy[..., None] + s * wheels[:, 0] + c * wheels[:, 1]
        worst = np.maximum(worst, np.abs(world.height(wx, wy) @ along))
    return np.degrees(np.arctan(worst))


def oracle_costmaps(
    base: CostMap,
    pitch_deg: np.ndarray,
    limit_deg: float,
    margin: float = 0.2,
    obstacle_margin: float = 0.3,
    soft_fraction: float = 0.6,
    weight: float = 20.0,
) -> tuple[CostMap, CostMap]:
    """``(hard, soft)`` cost maps from the sampler's ``base`` map and the wheel-pitch layer.

    ``soft`` = ``base`` + ``weight * excess**2``, ``excess`` the wheel pitch above ``soft_fraction`` of the
    limit (0..1), + the same penalty for coming within ``2 * obstacle_margin`` of an obstacle band;
    ``hard`` also bans cells whose pitch exceeds the limit and cells within ``obstacle_margin`` of the
    obstacle band (the planner's band is exactly the collision radius, which line-of-sight shortcuts, cut
    corners and heading drift would graze). ``pitch_deg`` is max-filtered over a disc of radius ``margin``
    (m) first: the drift allowance around steep cells. Untraversable cells of ``base`` stay untraversable.
    """
    res = base.resolution
    r = math.ceil(margin / res)
    if r > 0:
        yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
        disc = np.hypot(xx, yy) <= margin / res + 1e-9
        pitch_deg = ndi.maximum_filter(pitch_deg, footprint=disc, mode="nearest")
    lo = soft_fraction * limit_deg
    excess = np.clip((pitch_deg - lo) / max(limit_deg - lo, 1e-9), 0.0, 1.0)
    soft = base.cost + weight * excess**2  # inf stays inf
    hard_ban = pitch_deg > limit_deg
    band = base.layers.get("obstacle")
    if band is not None and band.any() and obstacle_margin > 0:
        clearance = ndi.distance_transform_edt(~band) * res  # m from the nearest banded cell
        near = np.clip(1.0 - clearance / (2.0 * obstacle_margin), 0.0, 1.0)
        soft = soft + weight * near**2
        hard_ban |= clearance <= obstacle_margin
    hard = np.where(hard_ban, np.inf, soft)
    layers = {**base.layers, "wheel_pitch_deg": pitch_deg}
    return (
        CostMap(cost=hard, resolution=res, x_min=base.x_min, y_min=base.y_min, layers=layers),
        CostMap(cost=soft, resolution=res, x_min=base.x_min, y_min=base.y_min, layers=layers),
    )


class AStarOracle:
    """Follows the least-cost path over the oracle's cost maps (see the module docstring).

    Args:
        spacing: the longest waypoint step as a fraction of the action space's extent (< 1 keeps every
            waypoint inside the action space whatever the heading; shorter steps drift less off the path).
        replan_distance: re-plan when a step ends farther than this from the waypoint sent (the controller
            stops within its position tolerance of a waypoint it reached).
        margin: drift allowance (m) around steep cells, see :func:`oracle_costmaps`.
        obstacle_margin: clearance (m) kept beyond the planner's obstacle band, see :func:`oracle_costmaps`.
        plain: plan on the sampler's cost map only (no wheel-pitch layer): the planner's own view.
        receding: choose every waypoint afresh from wherever the rover is, by a one-step look-ahead on
            the cost-to-go from the goal (:func:`~diana_lab.planning.next_waypoint`, one search per episode),
            instead of following one plan. The expert that labels a learner's states for imitation
            (:mod:`diana_lab.training.imitation`) must be this: its answer may depend only on the state.
        knowledge_radius: if set (m), the oracle knows the cost maps only this far around the rover and
            takes every other traversable cell as the cheapest ground (implies ``receding``, with one search
            per step). With ``knowledge_fov_deg`` it knows only a cone ahead (plus a 1 m disc), like a
            forward camera. Without ``knowledge_memory`` it forgets what it saw at the last step (a bound on
            what a policy that sees only its current frame can reach); with it, it keeps a map of everything
            seen in the episode (``policy=astar_memory``).
    """

    name = "astar"

    def __init__(
        self,
        spacing: float = 0.95,
        replan_distance: float = 0.5,
        margin: float = 0.2,
        obstacle_margin: float = 0.3,
        snap: float = 1.0,
        plain: bool = False,
        receding: bool = False,
        knowledge_radius: float | None = None,
        knowledge_fov_deg: float | None = None,
        knowledge_memory: bool = False,
    ) -> None:
        if not 0.0 < spacing <= 1.0:
            raise ValueError(f"AStarOracle.spacing: expected a fraction in (0, 1], got {spacing!r}")
        if knowledge_radius is not None and not knowledge_radius > 0.0:
            raise ValueError(f"AStarOracle.knowledge_radius: expected a positive radius (m), got {knowledge_radius!r}")
        if knowledge_fov_deg is not None and not 0.0 < knowledge_fov_deg <= 360.0:
            raise ValueError(f"AStarOracle.knowledge_fov_deg: expected (0, 360], got {knowledge_fov_deg!r}")
        self.knowledge_radius, self.knowledge_fov_deg = knowledge_radius, knowledge_fov_deg
        self.knowledge_memory = knowledge_memory
        self._seen: np.ndarray | None = None
        self.receding = receding or knowledge_radius is not None
        self.spacing, self.replan_distance, self.snap, self.plain = spacing, replan_distance, snap, plain
        self.margin, self.obstacle_margin = margin, obstacle_margin
        self._maps: dict[int, tuple[CostMap, ...]] = {}
        self.waypoints = np.zeros((0, 2))
        self.replans = 0
        self._next = 0
        self._sent: np.ndarray | None = None
        self.known: CostMap | None = None  # the first map the last plan tried, as the oracle knew it
        # receding over a discrete action space: every candidate's cost (segment + cost to go, ``inf``: no way)
        # on the map the last choice was made on, in action order; None when no map had a way
        self.candidate_costs: np.ndarray | None = None

    def costmaps(self, env: gym.Env) -> tuple[CostMap, ...]:
        """The maps to try in order (cached per cost map: one env, one world, one robot)."""
        base = env.unwrapped
        key = id(base.sampler.costmap)
        if key not in self._maps:
            cm = base.sampler.costmap
            if self.plain:
                self._maps[key] = (cm,)
            else:
                pitch = wheel_pitch_deg(base.world, base.robot, cm)
                self._maps[key] = (
                    *oracle_costmaps(cm, pitch, base.robot.max_slope_deg, self.margin, self.obstacle_margin),
                    cm,
                )
        return self._maps[key]

    def knowledge(self, env: gym.Env, grid: CostMap) -> np.ndarray | None:
        """Which cells of ``grid`` the oracle knows now (``None``: all; see ``knowledge_radius``)."""
        if self.knowledge_radius is None:
            return None
        est = env.unwrapped.pose_estimate
        ny, nx = grid.shape
        cx, cy = grid.cell_to_world(np.arange(nx), np.arange(ny))
        dx, dy = cx[None, :] - est.xy[0], cy[:, None] - est.xy[1]
        dist = np.hypot(dx, dy)
        known = dist <= self.knowledge_radius
        if self.knowledge_fov_deg is not None and self.knowledge_fov_deg < 360.0:
            bearing = np.angle(np.exp(1j * (np.arctan2(dy, dx) - est.yaw)))
            known &= (np.abs(bearing) <= math.radians(self.knowledge_fov_deg) / 2.0) | (dist <= 1.0)
        if self.knowledge_memory:  # a map built over the episode: everything seen so far stays known
            self._seen = known if self._seen is None or self._seen.shape != known.shape else self._seen | known
            known = self._seen
        return known

    def _known(self, env: gym.Env, maps: tuple[CostMap, ...]) -> Iterator[CostMap]:
        """``maps`` as far as the rover knows them (:meth:`knowledge`): unknown cells cost the least. Built as
        the planner asks for them: the first map almost always has a way, and each costs a pass over the grid."""
        known = self.knowledge(env, maps[0])
        if known is None:
            yield from maps
            return
        for cm in maps:
            cheapest = float(np.min(cm.cost[np.isfinite(cm.cost)], initial=1.0))
            cost = np.where(known, cm.cost, cheapest)  # nothing beyond the horizon, not even obstacles
            yield CostMap(cost=cost, resolution=cm.resolution, x_min=cm.x_min, y_min=cm.y_min, layers={})

    def _plan(self, env: gym.Env, start: np.ndarray) -> None:
        base = env.unwrapped
        reach = self.spacing * base.mapping.extent
        self.waypoints = np.asarray(base.goal, dtype=np.float64)[None, :]  # if nothing else: head for the goal
        self.known, self.candidate_costs = None, None
        for cm in self._known(env, self.costmaps(env)):
            if self.known is None:
                self.known = cm
            if self.receding:
                choices = None
                if base.mapping.discrete:  # choose among the actions the policy has, not the nearest to a free point
                    choices = np.asarray(start, dtype=np.float64) + base.mapping.world_offsets(base.pose_estimate.yaw)
                # a knowledge-limited map changes every step: search it only as far as this step needs
                choice = choose_waypoint(
                    cm,
                    start,
                    base.goal,
                    reach,
                    weighted=True,
                    snap=self.snap,
                    candidates=choices,
                    full_search=self.knowledge_radius is None,
                )
                if choice is not None:
                    self.waypoints, self.candidate_costs = choice.waypoint[None, :], choice.costs
                    break
            else:
                path = plan(cm, start, base.goal, weighted=True, snap=self.snap)
                if path is not None:
                    self.waypoints = simplify(path, reach)
                    break
        self._next, self._sent = 0, None

    def reset(self, env: gym.Env) -> None:
        self.replans = 0
        self._seen = None
        self._plan(env, env.unwrapped.pose_estimate.xy)

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        xy = env.unwrapped.pose_estimate.xy
        if self.receding and self._sent is not None:
            self._plan(env, xy)
        elif self._sent is not None:
            if math.dist(xy, self._sent) > self.replan_distance:
                self.replans += 1
                self._plan(env, xy)
            else:
                self._next = min(self._next + 1, len(self.waypoints) - 1)
        target = self.waypoints[self._next]
        self._sent = target
        return waypoint_action(env, target)
