"""The notebooks run top to bottom (papermill, tiny budgets through their parameters cell) and are committed
without outputs. Each executed copy is kept in the test's tmp folder (its path is printed) for a look.
The sweep notebook reads a study that ``python -m diana_lab.sweep`` makes with tiny budgets."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import nbformat
import pytest
from omegaconf import OmegaConf

from tests.training.helpers import ALGO_TINY, TINY

NOTEBOOKS = Path(__file__).resolve().parents[2] / "notebooks"
TINY_TRAIN = [o for o in TINY if not o.startswith("hydra/")] + ALGO_TINY["ppo"]


def execute(name: str, tmp: Path, parameters: dict, monkeypatch) -> nbformat.NotebookNode:
    import papermill

    # figures as PNG outputs (the test environment's Agg backend would only warn on plt.show())
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    out = tmp / f"executed_{name}"
    print(f"executed notebook: {out}")
    papermill.execute_notebook(
        str(NOTEBOOKS / name),
        str(out),
        parameters=parameters,
        kernel_name="python3",
        cwd=str(tmp),
        progress_bar=False,
        execution_timeout=600,
    )
    return nbformat.read(out, as_version=4)


def text_of(nb: nbformat.NotebookNode) -> str:
    parts = []
    for cell in nb.cells:
        for o in cell.get("outputs", []):
            parts.append(o.get("text", "") + json.dumps(o.get("data", {}).get("text/plain", "")))
    return "\n".join(parts)


def images(nb: nbformat.NotebookNode) -> int:
    return sum("image/png" in o.get("data", {}) for c in nb.cells for o in c.get("outputs", []))


@pytest.mark.parametrize("path", sorted(NOTEBOOKS.glob("*.ipynb")), ids=lambda p: p.name)
def test_committed_notebook_has_no_outputs_and_a_parameters_cell(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(c.outputs == [] and c.execution_count is None for c in code), f"{path.name}: clear its outputs"
    assert any("parameters" in c.metadata.get("tags", []) for c in code), f"{path.name}: no parameters cell"


def test_the_three_notebooks_exist():
    assert {p.name for p in NOTEBOOKS.glob("*.ipynb")} >= {
        "01_quickstart.ipynb",
        "02_compare_runs.ipynb",
        "03_sweep_analysis.ipynb",
    }


@pytest.mark.slow
def test_quickstart_builds_an_env_drives_the_oracle_and_trains(tmp_path, monkeypatch):
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    nb = execute(
        "01_quickstart.ipynb",
        tmp_path,
        {
            "WORLD": "flat",
            "SENSOR": ["sensor.width=16", "sensor.height=12"],
            "TRAIN_OVERRIDES": TINY_TRAIN,
            "TOTAL_TIMESTEPS": 256,
            "TRACKING_URI": uri,
            "RUN_DIR": str(tmp_path / "run"),
        },
        monkeypatch,
    )
    assert images(nb) >= 3  # hillshade, point cloud + depth, rendered frame
    text = text_of(nb)
    assert "eval_success_rate by step: [(128," in text
    assert "'world': 'flat'" in text and "'algo': 'ppo'" in text  # notebook runs are tagged like CLI runs
    assert (tmp_path / "run" / "model" / "model.zip").is_file()


def test_compare_notebook_groups_seeds_and_plots(compare_store, tmp_path, monkeypatch):
    nb = execute(
        "02_compare_runs.ipynb",
        tmp_path,
        {"TRACKING_URI": compare_store, "GROUP_BY": ["algo", "world"]},
        monkeypatch,
    )
    text = text_of(nb)
    assert "4 runs in 3 groups" in text
    assert images(nb) >= 3  # learning curves, final metrics, reward terms


SWEEP = [  # the flat reward-shaping sweep on tiny budgets: three trials of a 16 x 12 camera on flat ground
    "sweep=reward_shaping_flat",
    "sweep.n_trials=3",
    "sweep.timesteps=64",
    "sweep.eval_episodes=2",
    "sweep.eval_every=0",
    "sweep.sampler=random",
    "sweep.sampler_seed=0",
    "train.n_envs=2",
    "algo.n_steps=32",
    "algo.batch_size=32",
    "algo.n_epochs=1",
    "episode.max_steps=10",
    "algo.net_arch=[16]",
    "algo.extractor.cnn_channels=[4]",
    "hydra/job_logging=disabled",
    "hydra/hydra_logging=disabled",
]


def run_sweep(tmp: Path) -> str:
    """A study made by ``python -m diana_lab.sweep`` (in-process); its journal file."""
    from diana_lab.sweep import main

    journal = tmp / "optuna.journal"
    saved = sys.argv
    sys.argv = [
        "diana_lab.sweep",
        *SWEEP,
        f"sweep.storage={journal}",
        f"tracking.uri=sqlite:///{tmp}/mlflow.db",
        f"hydra.run.dir={tmp}/sweep",
    ]
    try:
        main()
    except SystemExit as exc:
        assert not exc.code, f"the sweep exited with {exc.code}"
    finally:
        sys.argv = saved
    return str(journal)


@pytest.mark.slow
def test_sweep_notebook_reproduces_the_best_trial(tmp_path, monkeypatch):
    import optuna
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    from diana_lab.config import compose

    journal = run_sweep(tmp_path)
    nb = execute(
        "03_sweep_analysis.ipynb", tmp_path, {"STORAGE": journal, "STUDY_NAME": "reward_shaping_flat"}, monkeypatch
    )
    assert images(nb) >= 3  # history, importances, slices (+ the best trial's curve)
    line = next(ln for ln in text_of(nb).splitlines() if ln.startswith("python -m diana_lab "))
    study = optuna.load_study(study_name="reward_shaping_flat", storage=JournalStorage(JournalFileBackend(journal)))
    cfg = compose(shlex.split(line)[3:])  # the printed line composes, with the best trial's values
    for key, value in study.best_trial.params.items():
        assert OmegaConf.select(cfg, key) == pytest.approx(value), key


def test_sweep_notebook_reads_the_shipped_reward_study(tmp_path, monkeypatch):
    """By default the notebook reads the Mars-yard reward study in docs/studies/ (no training, no MLflow store)."""
    journal = NOTEBOOKS.parent / "docs" / "studies" / "reward_shaping.journal"
    nb = execute("03_sweep_analysis.ipynb", tmp_path, {"STORAGE": str(journal)}, monkeypatch)
    text = text_of(nb)
    assert "study reward_shaping: " in text and "spearman" in text  # the study and its budget agreement
    assert "python -m diana_lab " in text and "reward.terms." in text  # the best trial's command
    assert images(nb) >= 4  # history, importances, slices, budget curves
