"""``python -m diana_lab`` as a user runs it: misspellings fail cleanly, Ctrl-C / SIGTERM stop cleanly."""

from __future__ import annotations

import signal
import subprocess
import time

import pytest

from .helpers import ALGO_TINY, TINY, run_subprocess, runs, store_args


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("algo=ppx", "Could not find 'algo/ppx'"),
        ("train.total_timestep=10", "train.total_timestep"),
    ],
)
def test_misspelling_exits_non_zero_without_traceback(override, expected, tmp_path):
    proc = run_subprocess([override, *store_args(tmp_path)], cwd=tmp_path)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0
    assert expected in err
    assert "Traceback" not in err
    assert not (tmp_path / "mlflow.db").exists()


@pytest.mark.parametrize(
    ("sig", "code"),
    [
        (signal.SIGINT, 130),
        pytest.param(signal.SIGTERM, 143, marks=pytest.mark.slow),
    ],
)
def test_interrupt_saves_checkpoint_and_marks_run_killed(sig, code, tmp_path):
    # no periodic checkpoints: the only one is what the interrupt saves
    args = [
        "algo=ppo",
        *TINY,
        *ALGO_TINY["ppo"],
        "train.total_timesteps=1000000",
        "train.checkpoint_every=0",
        "eval.every=0",
        *store_args(tmp_path),
    ]
    proc = run_subprocess(args, cwd=tmp_path)
    deadline = time.monotonic() + 180
    for line in proc.stdout:  # SB3's console table is flushed after every update
        if "total_timesteps" in line or time.monotonic() > deadline:
            break
    assert proc.poll() is None, proc.communicate()[1]
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    assert proc.returncode == code, err
    assert "Traceback" not in err and "interrupted at" in err, err
    assert any((tmp_path / "run" / "checkpoints").glob("rl_model_*_steps.zip")), err
    client, found = runs(tmp_path)
    assert [r.info.status for r in found] == ["KILLED"], err
    run = found[0]
    ckpts = [a.path for a in client.list_artifacts(run.info.run_id, "checkpoints")]
    assert len(ckpts) == 1 and ckpts[0].endswith("_steps.zip")
    steps = int(ckpts[0].rsplit("_", 2)[-2])
    assert 128 <= steps < 1_000_000


@pytest.mark.parametrize("sig", [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow)])
def test_an_interrupt_during_imitation_stops_the_run_cleanly(sig, tmp_path):
    # the imitation stage has its own loop (not SB3's): it must be a safe point for interrupts too
    args = [
        "algo=ppo",
        *TINY,
        *ALGO_TINY["ppo"],
        "train.imitation.enabled=true",
        "train.imitation.iterations=1000",
        "train.imitation.steps_per_iteration=32",
        "train.imitation.epochs=1",
        *store_args(tmp_path),
    ]
    proc = run_subprocess(args, cwd=tmp_path)
    seen = []
    for line in proc.stderr:  # the imitation stage reports each iteration on stderr
        seen.append(line)
        if line.startswith("imitation 2/1000"):
            break
    assert proc.poll() is None, "".join(seen) + proc.communicate()[1]
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    assert proc.returncode == {signal.SIGTERM: 143, signal.SIGINT: 130}[sig], err
    assert "Traceback" not in err, err
    _, found = runs(tmp_path)
    assert [r.info.status for r in found] == ["KILLED"], err


@pytest.mark.parametrize(("value", "traceback"), [("0", False), ("yes", False), ("1", True)])
def test_hydra_full_error_is_read_as_hydra_reads_it(value, traceback, tmp_path, monkeypatch, capsys):
    """Only ``HYDRA_FULL_ERROR=1`` shows the traceback: ``0`` (or any other word) keeps the one-paragraph error."""
    from diana_lab.cli import full_error
    from tests import entrypoints

    monkeypatch.setenv("HYDRA_FULL_ERROR", value)
    assert full_error() is traceback
    args = ["train.total_timesteps=-5", *store_args(tmp_path)]
    if traceback:
        with pytest.raises(Exception, match=r"train\.total_timesteps"):
            entrypoints.run_in_process("diana_lab.__main__", args)
    else:
        assert entrypoints.run_in_process("diana_lab.__main__", args) == 2
        err = capsys.readouterr().err
        assert "train.total_timesteps" in err and "Traceback" not in err
