"""Per-suite summary statistics with 95 % confidence intervals.

* Rates (success, collision, ...): Wilson score interval -- unlike the normal approximation it stays inside
  [0, 1] and is sensible at 0 % and 100 %, which is where good and bad policies live.
* Means (SPL, path length, speed, ...): Student-t interval over the episodes.
* ``time_over_15deg_frac`` is a ratio of sums (time over 15 degrees / total time); its interval uses the
  delta method (linearised ratio estimator), so nothing here is random and the summary is reproducible.

Undefined values (a mean over no successful episode) are NaN here and ``null`` in JSON (:func:`to_json`).
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from diana_lab.shield import VETO_CHECKS

__all__ = ["MIN_GOAL_SPEED", "SUMMARY_KEYS", "mean_ci", "ratio_ci", "spl", "summarize", "to_json", "wilson"]


# the summary's keys, in order; each one but the counts ``episodes`` and ``slow_successes`` and ``min_speed_mps`` also
# gets ``<key>_ci95``; a policy
# behind the slope shield adds ``shield_veto_rate``, ``shield_revisit_rate``, ``shield_fallback_rate``,
# ``shield_approach_rate``, ``shield_detour_rate``, ``shield_route_rate`` and ``shield_<check>_veto_rate`` (and their
# intervals) after them
# per-step rates from optional per-episode counts, (column, summary key), in the summary's order: behind the slope
# shield the decisions it changed, those its place rule changed (eval.shield.revisit_radius), those that found no
# candidate allowed (its tilt check dropped), those its final approach made (eval.shield.approach_radius), those its
# detour made (eval.shield.detour_after), those its route rule turned from the policy's choice (eval.shield.route),
# and the vetoes put down to each check (one veto can fail several); with
# the rover's tilt guard, the waypoints it halted
PER_STEP_RATES = (
    ("shield_vetoes", "shield_veto_rate"),
    ("shield_revisits", "shield_revisit_rate"),
    ("shield_fallbacks", "shield_fallback_rate"),
    ("shield_approaches", "shield_approach_rate"),
    ("shield_detours", "shield_detour_rate"),
    ("shield_routes", "shield_route_rate"),
    *((f"shield_{check}_vetoes", f"shield_{check}_veto_rate") for check in VETO_CHECKS),
    ("halts", "halt_rate"),
)
SUMMARY_KEYS = (
    "episodes",
    "success_rate",
    "spl",
    "collision_rate",
    "tipover_rate",
    "timeout_rate",
    "stuck_rate",
    "mean_path_length_m",
    "mean_sim_time_s",
    "mean_speed_mps",
    "mean_max_tilt_deg",
    "time_over_15deg_frac",
    "mean_waypoints",
    "min_speed_mps",
    "slow_successes",
)
# the paper's minimum goal-directed speed (m/s: a quarter of the 0.33 m/s cruise); ``eval.min_goal_speed``
MIN_GOAL_SPEED = 0.083
RATE_OUTCOMES = {
    "collision_rate": "collision",
    "tipover_rate": "tipover",
    "timeout_rate": "timeout",
    "stuck_rate": "stuck",
}


def wilson(successes: int, n: int) -> tuple[float, float]:
    """Wilson score 95 % interval of a binomial proportion (scipy's ``binomtest``); ``(nan, nan)`` without trials."""
    if n <= 0:
        return math.nan, math.nan
    ci = stats.binomtest(int(successes), int(n)).proportion_ci(confidence_level=0.95, method="wilson")
    # exact ends at 0 and n successes (the formula gives them up to rounding: 5e-17 is not a rate)
    lo = 0.0 if successes <= 0 else max(0.0, float(ci.low))
    hi = 1.0 if successes >= n else min(1.0, float(ci.high))
    return lo, hi


def mean_ci(values: np.ndarray) -> tuple[float, tuple[float, float]]:
    """Mean and its Student-t 95 % interval (NaNs ignored; the interval is NaN below two values)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, (math.nan, math.nan)
    mean = float(v.mean())
    if v.size < 2:
        return mean, (math.nan, math.nan)
    half = float(stats.t.ppf(0.975, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    return mean, (mean - half, mean + half)


def ratio_ci(num: np.ndarray, den: np.ndarray) -> tuple[float, tuple[float, float]]:
    """``sum(num) / sum(den)`` with a delta-method 95 % interval (clipped to [0, 1]: it is a fraction)."""
    a, b = np.asarray(num, dtype=np.float64), np.asarray(den, dtype=np.float64)
    if a.size == 0 or b.sum() <= 0:
        return math.nan, (math.nan, math.nan)
    r = float(a.sum() / b.sum())
    if a.size < 2:
        return r, (math.nan, math.nan)
    resid = a - r * b
    se = float(np.sqrt(resid.var(ddof=1) / a.size) / b.mean())
    half = float(stats.t.ppf(0.975, a.size - 1)) * se
    return r, (max(0.0, r - half), min(1.0, r + half))


def spl(success: np.ndarray, shortest: np.ndarray, driven: np.ndarray) -> np.ndarray:
    """Per-episode SPL term ``S_i * l_i / max(p_i, l_i)`` (Anderson et al. 2018); its mean is the suite's SPL.

    ``l_i`` is the planner's shortest traversable path, ``p_i`` the driven length. Failed episodes score 0;
    an episode without a finite shortest path (cannot happen for sampled suites) scores 0 as well.
    """
    s = np.asarray(success, dtype=bool)
    short = np.asarray(shortest, dtype=np.float64)
    p = np.asarray(driven, dtype=np.float64)
    ok = s & np.isfinite(short) & (short > 0)
    out = np.zeros(s.shape)
    out[ok] = short[ok] / np.maximum(p[ok], short[ok])
    return out


def summarize(df: pd.DataFrame, min_goal_speed: float = MIN_GOAL_SPEED) -> dict[str, Any]:
    """The suite's summary from :func:`~diana_lab.evaluation.runner.run_suite`'s rows (see SUMMARY_KEYS).
    ``slow_successes`` counts the successful episodes whose goal-directed speed is under ``min_goal_speed`` (m/s):
    the paper asks for none (its minimum met in every successful episode), a figure no mean or minimum gives."""
    n = len(df)
    success = df["success"].to_numpy(dtype=bool)
    out: dict[str, Any] = {"episodes": int(n)}

    def rate(key: str, hits: np.ndarray) -> None:
        k = int(np.count_nonzero(hits))
        out[key] = k / n if n else math.nan
        out[f"{key}_ci95"] = list(wilson(k, n))

    def mean(key: str, values: np.ndarray) -> None:
        m, ci = mean_ci(values)
        out[key], out[f"{key}_ci95"] = m, list(ci)

    rate("success_rate", success)
    mean("spl", spl(success, df["shortest_path_m"].to_numpy(), df["path_length_m"].to_numpy()) if n else [])
    out["spl_ci95"] = [min(max(v, 0.0), 1.0) if math.isfinite(v) else v for v in out["spl_ci95"]]  # SPL is in [0, 1]
    outcome = df["outcome"].to_numpy(dtype=object)
    for key, name in RATE_OUTCOMES.items():
        rate(key, outcome == name)
    mean("mean_path_length_m", df["path_length_m"].to_numpy())
    mean("mean_sim_time_s", df["sim_time_s"].to_numpy())
    speeds = df["speed_mps"].to_numpy(dtype=np.float64)[success]
    mean("mean_speed_mps", speeds)
    mean("mean_max_tilt_deg", df["max_tilt_deg"].to_numpy())
    frac, ci = ratio_ci(df["time_over_15deg_s"].to_numpy(), df["sim_time_s"].to_numpy())
    out["time_over_15deg_frac"], out["time_over_15deg_frac_ci95"] = frac, list(ci)
    mean("mean_waypoints", df["steps"].to_numpy())
    finite = speeds[np.isfinite(speeds)]
    out["min_speed_mps"] = float(finite.min()) if finite.size else math.nan
    out["slow_successes"] = int(np.count_nonzero(finite < min_goal_speed))
    steps = int(df["steps"].sum())
    for column, key in PER_STEP_RATES:  # optional counts per episode -> their share of all steps (decisions)
        if column in df:
            count = int(df[column].sum())
            out[key] = count / steps if steps else math.nan
            out[f"{key}_ci95"] = list(_step_rate_ci(df[column].to_numpy(), df["steps"].to_numpy()))
    return {k: _plain(v) for k, v in out.items()}


def _step_rate_ci(counts: np.ndarray, steps: np.ndarray) -> tuple[float, float]:
    """95 % interval of a share of all steps from per-episode counts: the hull of the ratio interval over
    episodes (a rover's decisions cluster: one episode stuck at a wall makes most of a suite's detours, and a
    binomial over steps alone is then far too narrow) and the Wilson interval over steps (which stays sensible
    where the ratio's collapses: no event in any episode, or a single episode)."""
    total, n = int(np.sum(counts)), int(np.sum(steps))
    w_lo, w_hi = wilson(total, n)
    _, (r_lo, r_hi) = ratio_ci(counts, steps)
    if not (math.isfinite(r_lo) and math.isfinite(r_hi)):
        return w_lo, w_hi
    return min(w_lo, r_lo), max(w_hi, r_hi)


def _plain(v: Any) -> Any:
    """Python floats/ints/lists (no numpy scalars), so that the summary serialises the same everywhere."""
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    if isinstance(v, bool | np.bool_):
        return bool(v)
    if isinstance(v, int | np.integer):
        return int(v)
    return float(v)


def _nan_to_none(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _nan_to_none(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_nan_to_none(x) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def to_json(summary: dict[str, Any]) -> str:
    """Strict JSON (NaN and inf become ``null``), stable key order, newline-terminated."""
    return json.dumps(_nan_to_none(summary), indent=2, allow_nan=False) + "\n"
