"""The tilt guard in an episode: the env reports each halt and where the guard tripped, the evaluation counts
halts per episode (``halts``) and their share of waypoints (``halt_rate``), and neither appears without it."""

from __future__ import annotations

import numpy as np
import pytest

from diana_lab.config import compose
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.evaluation import StraightLine
from diana_lab.evaluation.metrics import summarize
from diana_lab.evaluation.runner import run_episodes
from diana_lab.evaluation.suite import EpisodeSpec
from tests.sim.test_tilt_guard import twisting_ramp

INTO_THE_TWIST = [EpisodeSpec(np.array([-3.0, 0.0]), 0.0, np.array([8.0, 0.0]), seed=1)]


def ramp_env(*overrides: str) -> RoverNavEnv:
    cfg = compose(["episode.max_steps=8", "sensor.encoding=depth_image", *overrides])
    return RoverNavEnv(config=cfg, world_instance=twisting_ramp())


def test_the_env_reports_a_halt_and_where_the_guard_tripped():
    env = ramp_env("robot.tilt_guard_deg=20", "action_space=square")
    try:
        spec = INTO_THE_TWIST[0]
        env.reset(seed=1, options=spec.reset_options())
        assert env.unwrapped.last_waypoint is None
        outcomes = []
        for _ in range(3):  # straight at the goal, 3.5 m at a time: onto the twist
            _, _, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
            outcomes.append(info["waypoint_outcome"])
            assert env.unwrapped.last_waypoint.outcome == info["waypoint_outcome"]
            if info["waypoint_outcome"] == "halted":
                break
        assert outcomes[-1] == "halted" and not terminated
        assert info["halts"] == 1
        hx, hy = info["hazard_xy"]
        assert 0.0 < hx < 4.0 and hy == pytest.approx(0.0, abs=1e-6)
        assert info["position"][0] < hx - 1.0  # backed off
    finally:
        env.close()


@pytest.mark.parametrize("guard", [20.0, None])
def test_the_evaluation_counts_halts_only_with_the_guard(guard):
    env = ramp_env(f"robot.tilt_guard_deg={'null' if guard is None else guard}")
    try:
        df, _ = run_episodes(StraightLine(), env, INTO_THE_TWIST)
    finally:
        env.close()
    summary = summarize(df)
    if guard is None:
        assert "halts" not in df and "halt_rate" not in summary
        assert df["outcome"].iloc[0] == "tipover"
        return
    halts, steps = int(df["halts"].iloc[0]), int(df["steps"].iloc[0])
    assert halts >= 1 and df["outcome"].iloc[0] != "tipover"
    assert summary["halt_rate"] == pytest.approx(halts / steps)
    lo, hi = summary["halt_rate_ci95"]
    assert lo <= summary["halt_rate"] <= hi
