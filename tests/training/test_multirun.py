"""``python -m diana_lab -m ... hydra/launcher=joblib``: a multirun's jobs in parallel processes, each its own
MLflow run and its own job folder and log file."""

from __future__ import annotations

import pytest

from .helpers import run_subprocess, runs

# +experiment=quick at its smallest: one PPO rollout (4 envs x 128 steps), a 2-episode final evaluation
QUICK_TINY = [
    "+experiment=quick",
    "train.total_timesteps=512",
    "train.checkpoint_every=0",
    "eval.every=0",
    "eval.episodes=2",
    "eval.plots=false",
]


@pytest.mark.slow
def test_a_joblib_multirun_gives_every_job_its_own_finished_mlflow_run(tmp_path):
    args = [
        "-m",
        *QUICK_TINY,
        "seed=0,1",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        f"tracking.uri=sqlite:///{tmp_path}/mlflow.db",
        f"hydra.sweep.dir={tmp_path}/multirun",
    ]
    proc = run_subprocess(args, cwd=tmp_path)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    assert "Joblib.Parallel(" in out + err and "is launching 2 jobs" in out + err  # the joblib launcher ran them
    _, found = runs(tmp_path)
    assert [r.info.status for r in found] == ["FINISHED", "FINISHED"], err
    assert sorted(r.data.params["seed"] for r in found) == ["0", "1"]
    assert sorted(r.data.tags.get("hydra_job") for r in found) == ["0", "1"]
    assert len({r.data.tags.get("run_dir") for r in found}) == 2
    for job in ("0", "1"):  # each job's console lines in its own log file
        text = "".join(p.read_text() for p in (tmp_path / "multirun" / job).glob("*.log"))
        assert "[train] 512/512 steps (100%)" in text and "training FPS" in text
