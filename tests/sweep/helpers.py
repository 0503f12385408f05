"""Tiny sweeps for tests: a sweep file with minimal budgets, runs in-process or as subprocesses, and readers."""

from __future__ import annotations

import subprocess
from pathlib import Path

import optuna
import yaml
from mlflow.tracking import MlflowClient

from tests import entrypoints
from tests.presets import CAMERA_SQUARE

ROOT = Path(__file__).resolve().parents[2]

# a flat world, a 16 x 12 camera, 20-step episodes, a network of a few hundred weights, no files but the model
TINY_BASE = [
    "world=flat",
    *CAMERA_SQUARE,
    "sensor.width=16",
    "sensor.height=12",
    "episode.max_steps=20",
    "train.n_envs=2",
    "train.checkpoint_every=0",
    "train.progress_bar=false",
    "eval.plots=false",
    "eval.video=false",
    "algo.net_arch=[16]",
    "algo.extractor.cnn_channels=[4]",
    "algo.extractor.sensor_features=8",
    "algo.extractor.goal_hidden=[8]",
    "algo.n_steps=64",
    "algo.batch_size=64",
    "algo.n_epochs=1",
    "tracking.log_checkpoints=false",
]

TINY_PARAMS = {
    "algo.learning_rate": "tag(log, interval(1e-4, 1e-2))",
    "reward.terms.goal.weight": "interval(1, 20)",
}


def write_sweep(
    directory: Path,
    name: str = "tiny",
    n_trials: int = 3,
    timesteps: int = 128,
    eval_every: int = 128,
    extra_base: list[str] | None = None,
    params: dict[str, str] | None = None,
) -> Path:
    """A sweep file in ``directory``; ``sweep.name=<its path>`` runs it."""
    data = {
        "base": [*TINY_BASE, *(extra_base or [])],
        "objective": {"metric": "spl", "direction": "maximize"},
        "budget": {"n_trials": n_trials, "timesteps": timesteps, "eval_episodes": 2, "eval_every": eval_every},
        "params": dict(params or TINY_PARAMS),
    }
    path = directory / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, width=1000))
    return path


def sweep_args(tmp: Path, sweep_file: Path, *extra: str, out: str = "out") -> list[str]:
    return [
        f"sweep={sweep_file}",
        f"sweep.storage={tmp}/optuna.journal",
        f"tracking.uri=sqlite:///{tmp}/mlflow.db",
        f"hydra.run.dir={tmp}/{out}",
        "hydra/job_logging=disabled",
        "hydra/hydra_logging=disabled",
        *extra,
    ]


def run_in_process(args: list[str]) -> int:
    """``python -m diana_lab.sweep <args>`` in this process; its exit status."""
    return entrypoints.run_in_process("diana_lab.sweep", args)


def run_subprocess(args: list[str], cwd: Path) -> subprocess.Popen:
    return entrypoints.run_subprocess("diana_lab.sweep", args, cwd, stderr=subprocess.STDOUT)


def load_study(tmp: Path, name: str = "tiny") -> optuna.Study:
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    return optuna.load_study(study_name=name, storage=JournalStorage(JournalFileBackend(str(tmp / "optuna.journal"))))


def states(study: optuna.Study) -> list[str]:
    return [t.state.name for t in study.get_trials(deepcopy=False)]


def mlflow_runs(tmp: Path, experiment: str = "diana_lab"):
    """``(client, parents, children)``: runs without and with a ``mlflow.parentRunId`` tag."""
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    exp = client.get_experiment_by_name(experiment)
    found = [] if exp is None else client.search_runs([exp.experiment_id], order_by=["start_time ASC"])
    parents = [r for r in found if "mlflow.parentRunId" not in r.data.tags]
    children = [r for r in found if "mlflow.parentRunId" in r.data.tags]
    return client, parents, children


_CALLS: dict[str, int] = {}


def fail_once(ctx, marker: str = "") -> float:
    """A reward term that raises once, in the middle of training: on its 10th call (the env's start-up checks
    call each term once per env), unless the marker file says it already did. The first trial of a sweep
    fails inside training, the later ones train normally."""
    _CALLS[marker] = _CALLS.get(marker, 0) + 1
    path = Path(marker)
    if _CALLS[marker] >= 10 and not path.exists():
        path.touch()
        raise RuntimeError("deliberate failure inside training (tests.sweep.helpers.fail_once)")
    return 0.0
