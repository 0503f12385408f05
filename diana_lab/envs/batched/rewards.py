"""The configured reward terms for many rovers at once.

Every built-in term of :mod:`diana_lab.envs.rewards` has an array form here that computes, for a whole batch,
what the scalar term computes for one rover (the same formula, in the same order). A term of the user's own
(``reward.terms.mine={fn: mypkg.mine, ...}``) still works: it is called rover by rover with the
:class:`~diana_lab.envs.rewards.RewardContext` the scalar env would build, and a one-time warning names it as
the slow path. The manager keeps the scalar :class:`~diana_lab.envs.rewards.RewardManager`'s order of terms,
so the weighted sum is added up in the same order too.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from diana_lab.envs import rewards as R
from diana_lab.envs.rewards import RewardContext, RewardManager
from diana_lab.sim.state import WaypointResult

__all__ = ["BatchContext", "BatchedRewards"]


@dataclass
class BatchContext:
    """What the terms may look at for one step of the rovers ``rows`` (arrays over those rovers).

    ``max_abs_roll``/``max_abs_pitch``: the largest ``|roll|``/``|pitch|`` of each waypoint's trace (radians);
    ``waypoint_outcome``: the waypoint's outcome names; ``outcome``: the episode's outcome names (``""`` where it
    goes on); ``context(k)`` the scalar context of the ``k``-th rover, for the terms that are not built in."""

    prev_distance: np.ndarray
    distance: np.ndarray
    heading_error: np.ndarray
    max_abs_roll: np.ndarray
    max_abs_pitch: np.ndarray
    duration: np.ndarray
    waypoint_outcome: np.ndarray
    outcome: np.ndarray
    step: np.ndarray
    path_length: np.ndarray
    start_distance: np.ndarray
    context: Callable[[int], RewardContext]
    prev_path_to_goal: np.ndarray | None = None  # NaN-filled arrays when no term reads the path to the goal
    path_to_goal: np.ndarray | None = None


def _tilt(max_abs: np.ndarray, deadband_deg: float = 5.0, power: float = 2.0) -> np.ndarray:
    return -(np.maximum(max_abs - math.radians(deadband_deg), 0.0) ** power)


def _flag(names: np.ndarray, *which: str) -> np.ndarray:
    return np.isin(names, which)


def _efficiency(b: BatchContext) -> np.ndarray:
    paid = _flag(b.outcome, "success") & (b.path_length > 0.0)
    return np.minimum(np.divide(b.start_distance, b.path_length, out=np.zeros(len(b.distance)), where=paid), 1.0)


# the array form of each built-in term: (batch context, **params) -> unweighted values
BUILT_IN: dict[Callable, Callable[..., np.ndarray]] = {
    R.progress: lambda b, scale=1.0: (b.prev_distance - b.distance) / scale,
    R.path_progress: lambda b, scale=1.0, stride=2, untraversable_cost=10.0: (
        (b.prev_path_to_goal - b.path_to_goal) / scale
    ),
    R.heading: lambda b: 1.0 - 2.0 * np.sqrt(np.minimum(np.abs(b.heading_error), math.pi) / math.pi),
    R.roll: lambda b, deadband_deg=5.0, power=2.0: _tilt(b.max_abs_roll, deadband_deg, power),
    R.pitch: lambda b, deadband_deg=5.0, power=2.0: _tilt(b.max_abs_pitch, deadband_deg, power),
    R.goal: lambda b: _flag(b.outcome, "success").astype(np.float64),
    R.efficiency: _efficiency,
    R.collision: lambda b: -_flag(b.outcome, "collision").astype(np.float64),
    R.tipover: lambda b: -_flag(b.outcome, "tipover").astype(np.float64),
    R.out_of_bounds: lambda b: -_flag(b.outcome, "out_of_bounds").astype(np.float64),
    R.stuck: lambda b: -_flag(b.outcome, "stuck").astype(np.float64),
    R.step: lambda b: np.full(len(b.distance), -1.0),
    R.time: lambda b, scale=10.0: -b.duration / scale,
    R.stall: lambda b: -_flag(b.waypoint_outcome, "stuck", "gave_up", "halted").astype(np.float64),
}


class BatchedRewards:
    """The terms of a :class:`RewardManager` (already resolved and checked), evaluated over a batch."""

    def __init__(self, manager: RewardManager) -> None:
        self.terms = manager.terms
        self.names = [name for name, *_ in self.terms]
        self.slow = [name for name, fn, weight, _ in self.terms if fn not in BUILT_IN and weight]
        self._warned = False

    def __call__(self, batch: BatchContext) -> tuple[np.ndarray, np.ndarray]:
        """``(total (n,), weighted terms (n, n_terms))``, the terms in :attr:`names` order."""
        n = len(batch.distance)
        values = np.zeros((n, len(self.terms)))
        total = np.zeros(n)
        for j, (_name, fn, weight, params) in enumerate(self.terms):
            if not weight:
                continue
            fast = BUILT_IN.get(fn)
            if fast is not None:
                values[:, j] = weight * np.asarray(fast(batch, **params), dtype=np.float64)
            else:
                self._warn_slow()
                values[:, j] = [weight * float(fn(batch.context(k), **params)) for k in range(n)]
            total += values[:, j]
        return total, values

    def _warn_slow(self) -> None:
        if not self._warned:
            self._warned = True
            warnings.warn(
                f"reward.terms.{', reward.terms.'.join(self.slow)}: not a built-in term, so the batched env "
                "(train.vec_env=batched) calls it rover by rover in Python (the slow path); the built-in terms of "
                "diana_lab.envs.rewards are computed for every rover at once",
                stacklevel=3,
            )


def waypoint_result(
    outcome: str, duration: float, length: float, trace: np.ndarray, hazard: np.ndarray
) -> WaypointResult:
    """The scalar :class:`WaypointResult` of one rover's kept trace (rows ``x, y, tilt_deg, roll, pitch, t, z``),
    for the terms that are not built in."""
    result = WaypointResult(
        outcome,  # type: ignore[arg-type]
        float(duration),
        float(length),
        trace[:, :2].copy(),
        trace[:, 2].copy(),
        trace[:, 3:5].copy(),
        trace_t=trace[:, 5].copy(),
    )
    if not np.isnan(hazard[0]):
        result.hazard_xy = hazard.copy()
    return result
