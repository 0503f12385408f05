"""A blown-up physics simulation ends the episode as ``sim_error`` and nothing else: the last step's observation
and reward stay finite (NaN there would reach the learner's buffers and VecNormalize statistics for good),
the next reset gives a working simulation again, and a training run carries on past it."""

from __future__ import annotations

import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pybullet as pb
import pytest
import torch

from diana_lab.config import compose
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.sim.physics import PhysicsDynamics
from diana_lab.training import RunContext, train
from tests.presets import CAMERA_SQUARE
from tests.reliability.helpers import TINY_BUDGET

SMALL = [
    *CAMERA_SQUARE,
    "world=flat",
    "world.size_x=20",
    "world.size_y=20",
    "dynamics=physics",
    "sensor.width=16",
    "sensor.height=12",
    "action_space.size=2",  # 1 m waypoints: physics steps stay short
]
FAULTS = {"nan-velocity": [math.nan, 0.0, 0.0], "exploding-velocity": [1e4, 0.0, 0.0]}


def blow_up(dynamics: PhysicsDynamics, velocity: list[float]) -> None:
    """What a solver blow-up looks like from outside: an absurd or NaN base velocity in the PyBullet client."""
    scene = dynamics.scene()
    pb.resetBaseVelocity(scene.robot_id, velocity, [0.0, 0.0, 0.0], physicsClientId=scene.client)


@pytest.fixture(scope="module")
def env():
    e = RoverNavEnv(config=compose(SMALL))
    yield e
    e.close()


def finite(obs: dict[str, np.ndarray]) -> bool:
    return all(bool(np.all(np.isfinite(v))) for v in obs.values())


@pytest.mark.parametrize("velocity", list(FAULTS.values()), ids=list(FAULTS))
def test_a_blown_up_state_mid_episode_is_a_finite_sim_error_and_reset_recovers(
    env: RoverNavEnv, velocity: list[float]
) -> None:
    env.reset(seed=0, options={"start": (0.0, 0.0), "goal": (8.0, 0.0), "yaw": 0.0})
    _, _, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert not (terminated or truncated)
    before = info["position"]
    blow_up(env.dynamics, velocity)
    obs, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert (terminated, truncated, info["outcome"]) == (True, False, "sim_error")
    assert finite(obs) and env.observation_space.contains(obs)
    assert math.isfinite(reward) and all(math.isfinite(v) for v in info["reward_terms"].values())
    np.testing.assert_allclose(info["position"], before, atol=0.2)  # the last sane pose, not the wreck
    assert math.isfinite(info["distance_to_goal"]) and math.isfinite(info["path_length"])

    # the next episodes drive normally: on the ground, no sim_error
    for seed in (1, 2):
        obs, info = env.reset(seed=seed)
        assert finite(obs)
        assert abs(info["position"][2] - env.robot.base_height) < 0.1  # standing on the flat ground
        _, reward, _, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        assert info["waypoint_outcome"] == "reached" and math.isfinite(reward)


def test_training_continues_past_a_sim_error_with_finite_weights_and_statistics(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The runner's envs meet one NaN blow-up early on; the run must finish its budget with a sane model."""
    calls = {"n": 0, "sim_error": 0, "after": 0}
    execute = PhysicsDynamics.execute

    def faulty_execute(self: PhysicsDynamics, waypoint: np.ndarray, controller: Any, pose_estimate: Any = None) -> Any:
        calls["n"] += 1
        if calls["n"] == 3:
            blow_up(self, [math.nan, 0.0, 0.0])
        result = execute(self, waypoint, controller, pose_estimate)
        if result.outcome == "sim_error":
            calls["sim_error"] += 1
        elif calls["sim_error"]:
            calls["after"] += 1
        return result

    monkeypatch.setattr(PhysicsDynamics, "execute", faulty_execute)
    cfg = compose(
        [
            *SMALL,
            "episode.min_distance=2",
            "episode.max_distance=6",
            "episode.max_steps=8",
            "algo=ppo",
            *TINY_BUDGET,
            "algo.normalize=true",
            "algo.net_arch=[8]",
            "algo.extractor.cnn_channels=[4]",
            "algo.extractor.sensor_features=8",
            "algo.extractor.goal_hidden=[8]",
            "tracking.enabled=false",
        ]
    )
    result = train(cfg, RunContext(tmp_path / "run"))
    assert result.status == "FINISHED" and result.num_timesteps >= 32
    assert calls["sim_error"] == 1 and calls["after"] > 5  # it happened, and training went on
    from stable_baselines3 import PPO

    model = PPO.load(str(tmp_path / "run" / "model" / "model.zip"), device="cpu")
    assert all(bool(torch.isfinite(p).all()) for p in model.policy.parameters())
    with open(tmp_path / "run" / "model" / "vecnormalize.pkl", "rb") as f:
        stats = pickle.load(f)
    for rms in [*stats.obs_rms.values(), stats.ret_rms]:
        assert np.all(np.isfinite(rms.mean)) and np.all(np.isfinite(rms.var))
