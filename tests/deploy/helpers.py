"""A tiny untrained policy saved in a training run's layout, and recorded rollouts for the parity tests.

The run folder holds ``model.zip``, ``vecnormalize.pkl`` and ``.hydra/config.yaml`` (what the evaluation
loader reads), so the export under test goes through the real loading code. The policy is built by the
agents factory and left untrained; its action head is scaled up so that its actions span [-1, 1] (and get
clipped) instead of staying near 0, which would make any waypoint comparison trivially small.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from diana_lab.agents.factory import build_model
from diana_lab.config import compose, to_object
from diana_lab.config.evaluation import EvalConfig
from diana_lab.core.rotations import pitch_matrix
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.sim.world import World
from tests.presets import CAMERA_SQUARE

SMALL_WORLD = [
    *CAMERA_SQUARE,
    "world=craters",
    "world.size_x=24",
    "world.size_y=24",
    "episode.min_distance=4",
    "episode.max_distance=12",
]
TINY_ALGO = [
    "algo.net_arch=[16]",
    "algo.extractor.goal_hidden=[16]",
    "algo.extractor.cnn_channels=[4,8]",
    "algo.extractor.sensor_features=16",
    "algo.extractor.point_hidden=[16]",
]
EVAL = EvalConfig()  # deterministic, no shield


def run_config(*overrides: str):
    return compose([*SMALL_WORLD, *TINY_ALGO, *overrides])


def make_run(run_dir: Path, cfg, world: World | None = None, normalize: bool = True) -> RoverNavEnv:
    """Build the env and a tiny model of ``cfg`` and save the model as a training run would; return the env."""
    env = RoverNavEnv(config=cfg, world_instance=world)
    venv = DummyVecEnv([lambda: env])
    algo = to_object("algo", cfg.algo)
    vn = None
    if normalize:
        vn = VecNormalize(venv, norm_obs=True, norm_reward=False, norm_obs_keys=["goal"], clip_obs=2.0)
        rng = np.random.default_rng(5)  # statistics far from (0, 1), and a clip that bites
        vn.obs_rms["goal"].mean = rng.normal(0.0, 0.3, 7)
        vn.obs_rms["goal"].var = rng.uniform(0.05, 0.5, 7)
    model = build_model(algo, vn if vn is not None else venv, seed=0)
    with torch.no_grad():
        head = getattr(model.policy, "action_net", None)
        if head is None:  # SAC / TD3 actors
            head = model.policy.actor.mu
            head = head[0] if isinstance(head, torch.nn.Sequential) else head
        head.weight.mul_(100.0)
        head.bias.add_(0.2)
    run_dir.mkdir(parents=True, exist_ok=True)
    model.save(run_dir / "model.zip")
    if vn is not None:
        vn.save(str(run_dir / "vecnormalize.pkl"))
    (run_dir / ".hydra").mkdir(exist_ok=True)
    OmegaConf.save(cfg, run_dir / ".hydra" / "config.yaml")
    return env


@dataclass
class Recording:
    """Per step: the pose estimate (x, y, z, roll, pitch, yaw), the goal, the sensor-frame cloud, the env's
    observation and the torch policy's waypoint (pose + ``WaypointMapping.offset``, before the map clamp);
    ``starts`` marks the first step of every episode (where a runtime with a map must reset it); ``hazards``
    where the last waypoint's wheels met ground they could not drive (``hazard_xy``, reported to the runtime
    before it decides), else None."""

    poses: list[np.ndarray]
    goals: list[np.ndarray]
    clouds: list[np.ndarray]
    observations: list[dict[str, np.ndarray]]
    waypoints: np.ndarray
    starts: list[bool]
    hazards: list[np.ndarray | None]


def sensor_frame_points(env: RoverNavEnv, frame) -> np.ndarray:
    """A frame's returns back in the sensor's body frame: ``R_mount^T (p_rover - mount)``, float64."""
    rotation = pitch_matrix(np.radians(env.sensor.cfg.mount_pitch_deg))
    return (frame.points.astype(np.float64) - env.sensor.mount) @ rotation


def record(env: RoverNavEnv, policy, n: int, seed: int = 0) -> Recording:
    """Roll ``policy`` (an evaluation ``SB3Policy`` or ``ShieldedPolicy``) out for ``n`` steps, resetting after
    every episode."""
    frames = []
    capture = env.sensor.capture

    def recording_capture(position, rpy):
        frame = capture(position, rpy)
        frames.append(frame)
        return frame

    env.sensor.capture = recording_capture
    try:
        rec = Recording([], [], [], [], np.empty((n, 2)), [], [])
        obs, _ = env.reset(seed=seed)
        policy.reset(env)  # as the evaluation does every episode (a shielded policy forgets its map)
        start = True
        for i in range(n):
            rec.starts.append(start)
            est, state = env.pose_estimate, env.dynamics.state
            rec.poses.append(np.array([*est.xy, state.position[2], est.roll, est.pitch, est.yaw]))
            rec.goals.append(env.goal.copy())
            rec.clouds.append(sensor_frame_points(env, frames[-1]))
            rec.observations.append(obs)
            last = env.last_waypoint
            rec.hazards.append(None if start or last is None else last.hazard_xy)
            action = policy.act(obs, env)
            rec.waypoints[i] = est.xy + env.mapping.offset(action, est.yaw)
            obs, _, terminated, truncated, _ = env.step(action)
            start = terminated or truncated
            if start:
                obs, _ = env.reset()
                policy.reset(env)
        return rec
    finally:
        del env.sensor.capture
