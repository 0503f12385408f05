"""Running the entry points as a user does (subprocesses) and reading what they left in a throw-away store."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from tests.presets import CAMERA_SQUARE

# one PPO update of 32 steps in one env, nothing else run or saved on the way: any preset trained for a test
TINY_BUDGET = [
    "train.n_envs=1",
    "train.total_timesteps=32",
    "train.checkpoint_every=0",
    "train.progress_bar=false",
    "train.final_eval=false",
    "eval.every=0",
    "algo.n_steps=32",
    "algo.batch_size=32",
    "algo.n_epochs=1",
]
# and no logging set-up
QUIET = ["hydra/job_logging=disabled", "hydra/hydra_logging=disabled"]

# a 20 m flat world, a 16 x 12 camera, 32 PPO steps: a model in a few seconds (its observation space is what
# the mismatch rows need, not its skill)
TINY_MODEL = [
    *CAMERA_SQUARE,
    "world=flat",
    "world.size_x=20",
    "world.size_y=20",
    "sensor.width=16",
    "sensor.height=12",
    "episode.min_distance=4",
    "episode.max_distance=9",
    "episode.max_steps=10",
    *TINY_BUDGET,
    "algo.net_arch=[8]",
    "algo.extractor.cnn_channels=[4]",
    "algo.extractor.sensor_features=8",
    "algo.extractor.goal_hidden=[8]",
    "tracking.enabled=false",
    *QUIET,
]

# what the evaluation of TINY_MODEL's world needs to run a single short episode
TINY_EVAL = [
    "world=flat",
    "world.size_x=20",
    "world.size_y=20",
    "eval.episodes=1",
    "eval.min_distance=4",
    "eval.max_distance=9",
    "eval.video=false",
    "eval.plots=false",
]


def run_cli(module: str, args: list[str], cwd: Path, *, full_error: bool = False, timeout: float = 300):
    """``python -m <module> <args>`` in ``cwd``; HYDRA_FULL_ERROR only when asked (a developer's shell may set
    it, and it changes what the user sees)."""
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONHASHSEED": "0"}
    env.pop("HYDRA_FULL_ERROR", None)
    if full_error:
        env["HYDRA_FULL_ERROR"] = "1"
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def train_tiny_model(root: Path) -> Path:
    """Train TINY_MODEL into ``root/run``; returns ``model/model.zip`` (``.hydra/config.yaml`` sits beside it)."""
    root.mkdir(parents=True, exist_ok=True)
    proc = run_cli("diana_lab", [*TINY_MODEL, f"hydra.run.dir={root / 'run'}"], cwd=root)
    assert proc.returncode == 0, proc.stderr
    model = root / "run" / "model" / "model.zip"
    assert model.is_file(), proc.stdout
    return model


def run_statuses(db: Path) -> list[str] | None:
    """Statuses of every run in the SQLite store at ``db`` (all experiments); ``None`` when there is no store."""
    if not db.exists():
        return None
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{db}")
    ids = [e.experiment_id for e in client.search_experiments()]
    return [r.info.status for r in client.search_runs(ids)] if ids else []
