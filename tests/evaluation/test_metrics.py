import json
import math

import numpy as np
import pandas as pd
import pytest

from diana_lab.config.evaluation import EvalConfig
from diana_lab.evaluation.metrics import (
    MIN_GOAL_SPEED,
    SUMMARY_KEYS,
    mean_ci,
    ratio_ci,
    spl,
    summarize,
    to_json,
    wilson,
)


def rows(**cols):
    n = len(next(iter(cols.values())))
    base = {
        "outcome": ["success"] * n,
        "success": [True] * n,
        "steps": [5] * n,
        "path_length_m": [10.0] * n,
        "sim_time_s": [40.0] * n,
        "straight_distance_m": [9.0] * n,
        "shortest_path_m": [10.0] * n,
        "speed_mps": [9.0 / 40.0] * n,
        "max_tilt_deg": [5.0] * n,
        "time_over_15deg_s": [0.0] * n,
    }
    base.update(cols)
    base["success"] = [o == "success" for o in base["outcome"]]
    return pd.DataFrame(base)


def test_spl_is_the_mean_of_success_weighted_path_ratios():
    # Anderson et al.: S_i * l_i / max(p_i, l_i); a detour halves the score, a failure scores 0,
    # driving less than the shortest path (stopping inside the goal tolerance) cannot exceed 1
    df = rows(
        outcome=["success", "success", "collision", "success"],
        shortest_path_m=[10.0, 10.0, 10.0, 8.0],
        path_length_m=[10.0, 20.0, 3.0, 7.5],
    )
    per = spl(df["success"], df["shortest_path_m"], df["path_length_m"])
    np.testing.assert_allclose(per, [1.0, 0.5, 0.0, 1.0])
    assert summarize(df)["spl"] == pytest.approx(2.5 / 4)


def test_spl_uses_the_shortest_path_not_the_straight_line():
    df = rows(outcome=["success"], straight_distance_m=[10.0], shortest_path_m=[14.0], path_length_m=[14.0])
    assert summarize(df)["spl"] == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("k", "n", "lo", "hi"),
    [(8, 10, 0.4902, 0.9433), (0, 10, 0.0, 0.2775), (10, 10, 0.7225, 1.0), (50, 100, 0.4038, 0.5962)],
)
def test_wilson_interval_matches_known_values(k, n, lo, hi):
    a, b = wilson(k, n)
    assert a == pytest.approx(lo, abs=1e-4)
    assert b == pytest.approx(hi, abs=1e-4)


def test_wilson_contains_the_rate_and_narrows_with_more_episodes():
    for n in (5, 50, 500):
        a, b = wilson(n // 5, n)
        assert a < 0.2 < b
    assert np.diff(wilson(20, 100)) < np.diff(wilson(2, 10))
    assert all(math.isnan(v) for v in wilson(0, 0))


def test_mean_and_ratio_intervals():
    m, (lo, hi) = mean_ci(np.array([1.0, 2.0, 3.0, 4.0]))
    assert m == 2.5 and lo < 2.5 < hi
    assert hi - m == pytest.approx(3.182446 * np.std([1, 2, 3, 4], ddof=1) / 2, rel=1e-5)  # t(0.975, 3)
    r, (lo, hi) = ratio_ci(np.array([1.0, 3.0, 0.0]), np.array([10.0, 10.0, 20.0]))
    assert r == pytest.approx(0.1) and 0.0 <= lo < r < hi <= 1.0


def test_summary_has_every_key_rates_add_up_and_serialises_without_nan():
    df = rows(outcome=["collision", "tipover", "stuck", "timeout"], time_over_15deg_s=[0.0, 10.0, 0.0, 0.0])
    s = summarize(df)
    for key in SUMMARY_KEYS:
        assert key in s
        if key not in ("episodes", "min_speed_mps", "slow_successes"):
            assert len(s[f"{key}_ci95"]) == 2
    assert s["episodes"] == 4 and s["success_rate"] == 0.0
    assert [s[k] for k in ("collision_rate", "tipover_rate", "stuck_rate", "timeout_rate")] == [0.25] * 4
    assert s["time_over_15deg_frac"] == pytest.approx(10.0 / 160.0)
    assert math.isnan(s["mean_speed_mps"]) and math.isnan(s["min_speed_mps"])  # no successful episode
    parsed = json.loads(to_json(s))  # strict JSON: NaN -> null
    assert parsed["mean_speed_mps"] is None and parsed["mean_speed_mps_ci95"] == [None, None]
    assert "NaN" not in to_json(s)


def test_speed_statistics_use_successful_episodes_only():
    df = rows(outcome=["success", "success", "collision"], speed_mps=[0.2, 0.3, float("nan")])
    s = summarize(df)
    assert s["mean_speed_mps"] == pytest.approx(0.25)
    assert s["min_speed_mps"] == pytest.approx(0.2)
    assert s["slow_successes"] == 0


def test_slow_successes_count_the_successes_under_the_minimum_goal_speed_and_only_those():
    """The issue's speed target is met only when no successful episode is slower than 0.083 m/s: a count, not the
    mean (0.2 here) or a minimum alone, says how far a policy is from it."""
    df = rows(outcome=["success", "success", "success", "timeout"], speed_mps=[0.05, 0.083, 0.3, 0.01])
    assert summarize(df)["slow_successes"] == 1  # 0.05 only: the timeout is no success, 0.083 is not under it
    assert summarize(df, min_goal_speed=0.1)["slow_successes"] == 2
    assert summarize(df, min_goal_speed=0.0)["slow_successes"] == 0
    assert MIN_GOAL_SPEED == EvalConfig().min_goal_speed == 0.083  # the paper's figure, one value in both places


def test_the_spl_interval_stays_within_zero_and_one():
    """A Student-t interval of few near-perfect episodes reached past 1 (an audit's 5 episodes: [0.805, 1.078])."""
    df = rows(outcome=["success"] * 4 + ["timeout"], path_length_m=[10.0, 10.0, 10.2, 11.0, 30.0])
    lo, hi = summarize(df)["spl_ci95"]
    raw = mean_ci(spl(df["success"], df["shortest_path_m"], df["path_length_m"]))[1]
    assert raw[1] > 1.0 and hi == 1.0 and lo == pytest.approx(raw[0])


def test_a_per_step_rate_interval_counts_episodes_not_only_steps():
    """Vetoes that all fall in one episode of ten are one event of the suite, not 30 of 300 independent steps:
    the interval must be wider than the binomial's over steps, and never narrower where no event happened."""
    clustered = rows(outcome=["success"] * 10, steps=[30] * 10, shield_vetoes=[30] + [0] * 9)
    s = summarize(clustered)
    binomial = wilson(30, 300)
    lo, hi = s["shield_veto_rate_ci95"]
    assert s["shield_veto_rate"] == pytest.approx(0.1)
    assert lo < binomial[0] and hi > binomial[1]  # 0.1 could be 0 or 0.3 from another ten episodes
    spread = rows(outcome=["success"] * 10, steps=[30] * 10, shield_vetoes=[3] * 10)
    assert summarize(spread)["shield_veto_rate_ci95"] == pytest.approx(list(binomial))  # no clustering: Wilson
    none = rows(outcome=["success"] * 10, steps=[30] * 10, shield_vetoes=[0] * 10)
    assert summarize(none)["shield_veto_rate_ci95"] == pytest.approx(list(wilson(0, 300)))
