"""Workers as users start them: two at once on one journal file, Ctrl-C / SIGTERM, SIGKILL, then a rerun."""

from __future__ import annotations

import signal
import subprocess
import time

import pytest

from .helpers import load_study, mlflow_runs, run_subprocess, states, sweep_args, write_sweep

pytestmark = pytest.mark.slow


def _finish(proc: subprocess.Popen, timeout: float = 300) -> str:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        raise AssertionError(f"worker did not finish in {timeout} s:\n{out[-3000:]}") from None
    return out


def _wait_for_training(proc: subprocess.Popen, timeout: float = 180) -> None:
    """Read the worker's output until SB3's first console table (training of trial 0 is under way)."""
    deadline = time.monotonic() + timeout
    assert proc.stdout is not None
    for line in proc.stdout:
        if "total_timesteps" in line or time.monotonic() > deadline:
            break
    assert proc.poll() is None, _finish(proc)


def test_two_concurrent_workers_share_the_budget(tmp_path):
    path = write_sweep(tmp_path, n_trials=4)
    workers = [run_subprocess(sweep_args(tmp_path, path, out=f"w{i}"), cwd=tmp_path) for i in range(2)]
    outputs = [_finish(w) for w in workers]
    for w, out in zip(workers, outputs):
        assert w.returncode == 0, out[-3000:]
    study = load_study(tmp_path)
    assert states(study) == ["COMPLETE"] * 4  # no trial lost, none run beyond the budget
    assert [t.number for t in study.trials] == [0, 1, 2, 3]
    _, parents, children = mlflow_runs(tmp_path)
    assert len(parents) == 1, [p.info.run_name for p in parents]  # one MLflow run per study
    assert sorted(int(r.data.tags["optuna_trial"]) for r in children) == [0, 1, 2, 3]  # each trial run once
    assert {r.data.tags["mlflow.parentRunId"] for r in children} == {parents[0].info.run_id}
    assert all(r.info.status == "FINISHED" for r in children)
    # every trial's run is the one its trial recorded
    assert {t.user_attrs["run_ids"][0] for t in study.trials} == {r.info.run_id for r in children}


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupt_fails_the_trial_kills_the_runs_and_a_rerun_resumes(sig, code, tmp_path):
    path = write_sweep(tmp_path, n_trials=2, timesteps=10_000_000, eval_every=0)
    worker = run_subprocess(sweep_args(tmp_path, path), cwd=tmp_path)
    _wait_for_training(worker)
    worker.send_signal(sig)
    out = _finish(worker, timeout=120)
    assert worker.returncode == code, out[-3000:]
    assert "Traceback" not in out and "rerun the same command" in out
    study = load_study(tmp_path)
    (trial,) = study.trials
    assert trial.state.name == "FAIL" and "interrupted" in trial.user_attrs and "error" not in trial.user_attrs
    _, (parent,), (child,) = mlflow_runs(tmp_path)
    assert child.info.status == "KILLED" and parent.info.status == "KILLED"

    # the rerun does not count the interrupted trial: two more complete, under the same MLflow run
    again = run_subprocess(
        sweep_args(tmp_path, path, "sweep.timesteps=128", "sweep.eval_every=128", out="again"), tmp_path
    )
    out = _finish(again)
    assert again.returncode == 0, out[-3000:]
    assert states(load_study(tmp_path)) == ["FAIL", "COMPLETE", "COMPLETE"]
    _, parents, children = mlflow_runs(tmp_path)
    assert [p.info.run_id for p in parents] == [parent.info.run_id] and parents[0].info.status == "FINISHED"
    assert len(children) == 3


def test_killed_worker_leaves_a_usable_study(tmp_path):
    path = write_sweep(tmp_path, n_trials=1, timesteps=10_000_000, eval_every=0)
    worker = run_subprocess(sweep_args(tmp_path, path), cwd=tmp_path)
    _wait_for_training(worker)
    worker.kill()  # SIGKILL: no handler runs, the trial stays RUNNING in the journal
    worker.wait(timeout=60)
    assert states(load_study(tmp_path)) == ["RUNNING"]
    again = run_subprocess(
        sweep_args(tmp_path, path, "sweep.timesteps=128", "sweep.eval_every=128", out="again"), tmp_path
    )
    out = _finish(again, timeout=300)  # must not hang on the dead worker's trial or lock
    assert again.returncode == 0, out[-3000:]
    assert "left RUNNING by a killed worker" in out
    assert states(load_study(tmp_path)) == ["FAIL", "COMPLETE"]
    _, (parent,), children = mlflow_runs(tmp_path)
    assert sorted(r.info.status for r in children) == ["FINISHED", "KILLED"] and parent.info.status == "FINISHED"


def test_local_workers_share_one_study_and_worker_zero_reports_every_trial(tmp_path):
    path = write_sweep(tmp_path, n_trials=4)
    proc = run_subprocess(sweep_args(tmp_path, path, "sweep.workers=2", "sweep.sampler_seed=3"), cwd=tmp_path)
    out = _finish(proc)
    assert proc.returncode == 0, out[-3000:]
    assert "worker 1: pid" in out and "study 'tiny': 4 complete, 0 pruned, 0 failed, 0 running" in out
    study = load_study(tmp_path)
    assert states(study) == ["COMPLETE"] * 4
    assert len({t.user_attrs["worker"] for t in study.trials}) == 2  # both processes ran trials
    assert len({tuple(sorted(t.params.items())) for t in study.trials}) == 4  # seeded apart: no repeated point
    log = (tmp_path / "out" / "worker_1.log").read_text()
    assert "Traceback" not in log
    assert list((tmp_path / "out" / "worker_1").glob("trial_*"))  # worker 1's trials under its own run dir
    _, parents, children = mlflow_runs(tmp_path)
    assert len(parents) == 1 and parents[0].info.status == "FINISHED" and len(children) == 4


def test_sigterm_to_worker_zero_stops_the_local_workers_and_fails_their_trials(tmp_path):
    path = write_sweep(tmp_path, n_trials=2, timesteps=10_000_000, eval_every=0)
    proc = run_subprocess(sweep_args(tmp_path, path, "sweep.workers=2"), cwd=tmp_path)
    _wait_for_training(proc)
    deadline = time.monotonic() + 120
    while len(load_study(tmp_path).trials) < 2 and time.monotonic() < deadline:  # worker 1's trial under way
        time.sleep(1)
    time.sleep(5)
    proc.send_signal(signal.SIGTERM)
    out = _finish(proc, timeout=200)
    assert proc.returncode == 143, out[-3000:]
    study = load_study(tmp_path)
    assert states(study) == ["FAIL", "FAIL"] and all("interrupted" in t.user_attrs for t in study.trials)
    _, (parent,), children = mlflow_runs(tmp_path)
    assert [r.info.status for r in children] == ["KILLED", "KILLED"] and parent.info.status == "KILLED"
