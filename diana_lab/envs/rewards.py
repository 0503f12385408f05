"""Reward terms as plain functions, configured as data (``reward.terms.<name>: {fn, weight, params}``).

Each term returns an unweighted value where positive is good (penalties return negative values); the
:class:`RewardManager` multiplies by the weight, sums, and reports every weighted term so that
``info["reward_terms"]`` shows what the agent was paid for. A sweep reweights terms without touching code.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from hydra.utils import get_method

from diana_lab.config.env import RewardConfig
from diana_lab.core.validation import ConfigError
from diana_lab.sim.state import WaypointResult


@dataclass(frozen=True)
class RewardContext:
    """Everything a term may look at for one step (one executed waypoint)."""

    prev_distance: float  # to the goal before the step (m)
    distance: float  # to the goal after the step (m)
    heading_error: float  # rad, goal bearing minus rover heading after the step
    waypoint: WaypointResult
    outcome: str | None  # episode outcome if the episode ended on this step
    step: int  # steps taken in the episode so far (including this one)
    path_length: float = 0.0  # metres driven in the episode so far (including this step)
    start_distance: float = 0.0  # straight-line distance from the episode's start to the goal (m)
    # the way to the goal the rover can drive (m; the planner's cost map), before and after the step: computed
    # only when a term reads it (its function has ``goal_field = True``), NaN otherwise
    prev_path_to_goal: float = math.nan
    path_to_goal: float = math.nan


# --------------------------------------------------------------------------- terms (paper section 5.3)
def progress(ctx: RewardContext, scale: float = 1.0) -> float:
    """Metres gained towards the goal in this step (negative when moving away)."""
    return (ctx.prev_distance - ctx.distance) / scale


def path_progress(ctx: RewardContext, scale: float = 1.0, stride: int = 2, untraversable_cost: float = 10.0) -> float:
    """Metres gained towards the goal along the way the rover can drive (negative when moving away), from the
    true position: ``progress`` measured as Habitat's PointNav reward measures it, by the geodesic distance.
    Why: on the straight line a drive into a dead end pays as well as one round it; along the drivable way only
    the drive round it pays. The env computes the distance field once per episode on the planner's cost map,
    coarsened by ``stride`` cells, a metre across an untraversable cell costing ``untraversable_cost``
    (:class:`~diana_lab.planning.goal_distance.GoalDistance`); training-time knowledge only, nothing the
    policy observes."""
    return (ctx.prev_path_to_goal - ctx.path_to_goal) / scale


path_progress.goal_field = True  # type: ignore[attr-defined]  # the env computes ctx.path_to_goal for it


def heading(ctx: RewardContext) -> float:
    """1 when facing the goal, -1 when facing away: ``1 - 2 sqrt(|error| / pi)`` (DIANA-Gym's shape)."""
    return 1.0 - 2.0 * math.sqrt(min(abs(ctx.heading_error), math.pi) / math.pi)


def _tilt_penalty(angles: np.ndarray, deadband_deg: float, power: float) -> float:
    if len(angles) == 0:
        return 0.0
    excess = max(float(np.abs(angles).max()) - math.radians(deadband_deg), 0.0)
    return -(excess**power)


def roll(ctx: RewardContext, deadband_deg: float = 5.0, power: float = 2.0) -> float:
    """Penalty on the largest roll of the step beyond the deadband (radians**power); none within it."""
    return _tilt_penalty(ctx.waypoint.trace_rp[:, 0], deadband_deg, power)


def pitch(ctx: RewardContext, deadband_deg: float = 5.0, power: float = 2.0) -> float:
    """Penalty on the largest pitch of the step beyond the deadband (radians**power); none within it."""
    return _tilt_penalty(ctx.waypoint.trace_rp[:, 1], deadband_deg, power)


def goal(ctx: RewardContext) -> float:
    return 1.0 if ctx.outcome == "success" else 0.0


def efficiency(ctx: RewardContext) -> float:
    """On the step an episode succeeds, the straight line from its start to the goal over the path driven (at
    most 1); 0 otherwise. Why: progress pays the same for any path to the goal (it adds up to the start
    distance), so without this term only the step penalty and the discount tell a detour from the direct way;
    this one pays a successful episode for how short its path was, as SPL scores it (against the straight line
    rather than the shortest path, which would take a search of the map at every reset)."""
    if ctx.outcome != "success" or ctx.path_length <= 0.0:
        return 0.0
    return min(ctx.start_distance / ctx.path_length, 1.0)


def collision(ctx: RewardContext) -> float:
    return -1.0 if ctx.outcome == "collision" else 0.0


def tipover(ctx: RewardContext) -> float:
    return -1.0 if ctx.outcome == "tipover" else 0.0


def out_of_bounds(ctx: RewardContext) -> float:
    return -1.0 if ctx.outcome == "out_of_bounds" else 0.0


def stuck(ctx: RewardContext) -> float:
    """-1 on the step the episode ends stuck (no net progress for ``episode.stuck_steps`` waypoints): the failure
    the tilt guard leaves, which is otherwise charged only by the progress it forgoes."""
    return -1.0 if ctx.outcome == "stuck" else 0.0


def step(ctx: RewardContext) -> float:
    """-1 per waypoint: a time penalty that favours short episodes."""
    return -1.0


def time(ctx: RewardContext, scale: float = 10.0) -> float:
    """Simulated seconds spent on the step, negative (per ``scale`` seconds)."""
    return -ctx.waypoint.duration / scale


def stall(ctx: RewardContext) -> float:
    """-1 when the controller could not finish the waypoint (stuck at a slope, gave up, or the rover's tilt guard
    halted it: ground it could not drive, as a slope it could not climb)."""
    return -1.0 if ctx.waypoint.outcome in ("stuck", "gave_up", "halted") else 0.0


# --------------------------------------------------------------------------- manager
def _probe_context() -> RewardContext:
    """An ordinary step (1 m of progress, a reached waypoint, no outcome) to try every term on once."""
    trace = np.zeros((2, 2))
    result = WaypointResult("reached", 3.0, 1.0, trace, np.zeros(2), trace.copy())
    return RewardContext(10.0, 9.0, 0.1, result, None, 1, 1.0, 10.0, 11.0, 10.0)


def _check_term(name: str, path: str, fn: Callable[..., float], params: dict) -> None:
    """Evaluate a term once at start-up: params it cannot work with (``scale: 0``, a string where a number
    belongs) fail here naming the key, not as a ``ZeroDivisionError`` in the middle of training."""
    try:
        value = float(fn(_probe_context(), **params))
    except Exception as exc:
        raise ConfigError(
            f"reward.terms.{name}.params: {path}(ctx, **{params}) fails on an ordinary step "
            f"({type(exc).__name__}: {exc}); expected params that give a finite reward"
        ) from exc
    if not math.isfinite(value):
        raise ConfigError(
            f"reward.terms.{name}.params: {path}(ctx, **{params}) gives {value} on an ordinary step; "
            "expected a finite reward"
        )


class RewardManager:
    """Resolves the configured terms once and evaluates them every step."""

    def __init__(self, cfg: RewardConfig) -> None:
        self.terms: list[tuple[str, Callable[..., float], float, dict]] = []
        for name, term in cfg.terms.items():
            try:
                fn = get_method(term.fn)
            except Exception as exc:
                raise ConfigError(f"reward.terms.{name}.fn: cannot import '{term.fn}' ({exc})") from exc
            params = dict(term.params)
            accepted = set(inspect.signature(fn).parameters) - {"ctx"}
            unknown = set(params) - accepted
            if unknown:
                raise ConfigError(
                    f"reward.terms.{name}.params: unknown parameter(s) {sorted(unknown)} for "
                    f"{term.fn}; it accepts {sorted(accepted) or 'none'}"
                )
            _check_term(name, term.fn, fn, params)
            self.terms.append((name, fn, float(term.weight), params))
        self.goal_field = self._goal_field()

    def _goal_field(self) -> tuple[int, float] | None:
        """``(stride, untraversable_cost)`` of the goal-distance field the weighted terms read (``None``: no
        term reads it, and the env computes none). Every term reading it must ask for the same field."""
        wanted: dict[tuple[int, float], str] = {}
        for name, fn, weight, params in self.terms:
            if not weight or not getattr(fn, "goal_field", False):
                continue
            signature = inspect.signature(fn).parameters
            stride, cost = (
                params[key] if key in params else signature[key].default if key in signature else default
                for key, default in (("stride", 2), ("untraversable_cost", 10.0))
            )
            if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
                raise ConfigError(
                    f"reward.terms.{name}.params.stride: expected a whole number of cells >= 1, got {stride!r}"
                )
            if isinstance(cost, bool) or not isinstance(cost, int | float) or not math.isfinite(cost) or cost < 1.0:
                raise ConfigError(
                    f"reward.terms.{name}.params.untraversable_cost: expected a finite number >= 1, got {cost!r}"
                )
            wanted[(int(stride), float(cost))] = name
        if len(wanted) > 1:
            raise ConfigError(
                f"reward.terms.{', reward.terms.'.join(wanted.values())}: they read goal-distance fields of different "
                "params (stride, untraversable_cost); expected one field for every term"
            )
        return next(iter(wanted), None)

    def __call__(self, ctx: RewardContext) -> tuple[float, dict[str, float]]:
        values = {name: weight * float(fn(ctx, **params)) if weight else 0.0 for name, fn, weight, params in self.terms}
        return float(sum(values.values())), values
