"""Tiny-budget runs of ``python -m diana_lab``, in-process (through the real Hydra app) or as a subprocess."""

from __future__ import annotations

import subprocess
from pathlib import Path

from mlflow.tracking import MlflowClient

from tests import entrypoints

ROOT = Path(__file__).resolve().parents[2]

# a flat world, a 16 x 12 camera, short episodes, 2 evaluation episodes without plots or GIF; the envs are the
# default's (kinematic, so train.vec_env=auto batches them; the discrete action space, which ALGO_TINY swaps for
# the square where an algorithm needs a Box)
TINY = [
    "world=flat",
    "sensor=depth_camera",
    "robot.tilt_guard_deg=null",
    "sensor.width=16",
    "sensor.height=12",
    "episode.max_steps=20",
    "train.n_envs=2",
    "train.total_timesteps=256",
    "train.checkpoint_every=128",
    "train.progress_bar=false",
    "eval.episodes=2",
    "eval.every=128",
    "eval.plots=false",
    "eval.video=false",
    "algo.net_arch=[16]",
    "algo.extractor.cnn_channels=[4]",
    "algo.extractor.sensor_features=8",
    "algo.extractor.goal_hidden=[8]",
    "hydra/job_logging=disabled",
    "hydra/hydra_logging=disabled",
]

# per algorithm: enough to run an update within the budget
ALGO_TINY = {
    "ppo": ["algo.n_steps=64", "algo.batch_size=64", "algo.n_epochs=1"],
    "a2c": ["algo.n_steps=8"],
    **{
        a: ["action_space=square", "algo.learning_starts=64", "algo.batch_size=16", "algo.buffer_size=1000"]
        for a in ("sac", "td3", "ddpg", "tqc")
    },
}


def store_args(tmp: Path, run_dir: str = "run") -> list[str]:
    return [f"tracking.uri=sqlite:///{tmp}/mlflow.db", f"hydra.run.dir={tmp}/{run_dir}"]


def run_in_process(args: list[str]) -> int:
    """``python -m diana_lab <args>`` in this process; its exit status."""
    return entrypoints.run_in_process("diana_lab.__main__", args)


def run_subprocess(args: list[str], cwd: Path, **kwargs) -> subprocess.Popen:
    return entrypoints.run_subprocess("diana_lab", args, cwd, **kwargs)


def runs(tmp: Path, experiment: str = "diana_lab"):
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    exp = client.get_experiment_by_name(experiment)
    return client, ([] if exp is None else client.search_runs([exp.experiment_id], order_by=["start_time ASC"]))
