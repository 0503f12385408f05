"""A sweep on several machines, for real: one PostgreSQL study storage and one MLflow tracking server (both
started on loopback for the module), and the same ``python -m diana_lab.sweep ...`` run by several workers.

Part A: two workers together run a study's ``n_trials``, each trial once, nested under one MLflow run.
Part B: a worker of "another machine" (its host name is not this one's, so no worker here can tell from its pid
that it died) is SIGKILLed mid-trial; once its heartbeats stop, a worker here fails that trial, ends its MLflow
run and runs the study's budget.

If PostgreSQL cannot be started the tests fail with the reason (``./dev setup`` installs it), never skip.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import optuna
import pytest
from mlflow.tracking import MlflowClient

from tests.entrypoints import ROOT

from .helpers import run_subprocess, sweep_args, write_sweep
from .postgres import PostgresUnavailable, postgres_server
from .test_workers import _finish, _wait_for_training

pytestmark = pytest.mark.slow

HEARTBEAT_S = 2  # RDB storages fail a dead worker's trial after 2 missed heartbeats: 4 s
OTHER_HOST = "machine-b"


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def _mlflow_server(root: Path) -> Iterator[str]:
    """``mlflow server`` on a free loopback port (SQLite backend, proxied artefacts in ``root``); its URL."""
    port = _free_port()
    log = root / "mlflow_server.log"
    cmd = [
        sys.executable,
        "-m",
        "mlflow",
        "server",
        "--backend-store-uri",
        f"sqlite:///{root}/server.db",
        "--serve-artifacts",
        "--artifacts-destination",
        str(root / "artifacts"),
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--workers",
        "1",
    ]
    url = f"http://127.0.0.1:{port}"
    with log.open("w") as out:
        proc = subprocess.Popen(cmd, cwd=root, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while True:
            if proc.poll() is not None:
                pytest.fail(f"mlflow server exited ({proc.returncode}):\n{log.read_text()[-3000:]}")
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=2) as answer:
                    if answer.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                pytest.fail(f"mlflow server did not answer on {url} in 120 s:\n{log.read_text()[-3000:]}")
            time.sleep(0.5)
        yield url
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)  # its own session: the server and the workers it started
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=30)


@pytest.fixture(scope="module")
def services(tmp_path_factory) -> Iterator[tuple[str, str]]:
    """``(PostgreSQL URL, MLflow server URL)``, shared by the module's tests (each its own study and experiment)."""
    root = tmp_path_factory.mktemp("services")
    with contextlib.ExitStack() as stack:
        try:
            db = stack.enter_context(postgres_server())
        except PostgresUnavailable as exc:
            pytest.fail(f"PostgreSQL could not be started: {exc}")
        yield db, stack.enter_context(_mlflow_server(root))


def _args(tmp: Path, sweep_file: Path, services: tuple[str, str], experiment: str, out: str, *extra: str):
    """A worker's command line: the shared study storage and tracking server, its own Hydra run dir."""
    db, server = services
    own = [a for a in sweep_args(tmp, sweep_file, out=out) if not a.startswith(("sweep.storage=", "tracking.uri="))]
    return [
        *own,
        f"sweep.storage={db}",
        f"tracking.uri={server}",
        f"tracking.experiment={experiment}",
        f"sweep.heartbeat_s={HEARTBEAT_S}",
        *extra,
    ]


def _other_machine(args: list[str], cwd: Path) -> subprocess.Popen:
    """``python -m diana_lab.sweep args`` as on another machine: ``socket.gethostname()`` says OTHER_HOST, so the
    trials it records are not this machine's (a worker here cannot see whether that pid is alive)."""
    code = (
        "import socket, sys\n"
        f"socket.gethostname = lambda: {OTHER_HOST!r}\n"
        "from diana_lab.sweep import main\n"
        "sys.argv = ['diana_lab.sweep', *sys.argv[1:]]\n"
        "main()\n"
    )
    env = {**os.environ, "PYTHONHASHSEED": "0", "PYTHONPATH": str(ROOT)}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.Popen(
        [sys.executable, "-c", code, *args],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _runs(server: str, experiment: str):
    """``(parents, children)`` of the server's experiment: runs without and with ``mlflow.parentRunId``."""
    client = MlflowClient(server)
    exp = client.get_experiment_by_name(experiment)
    assert exp is not None, f"no experiment {experiment!r} on {server}"
    found = client.search_runs([exp.experiment_id], order_by=["start_time ASC"])
    return (
        [r for r in found if "mlflow.parentRunId" not in r.data.tags],
        [r for r in found if "mlflow.parentRunId" in r.data.tags],
    )


def test_two_workers_share_one_postgres_study_and_one_mlflow_server(services, tmp_path):
    db, server = services
    path = write_sweep(tmp_path, name="shared", n_trials=4)
    workers = [run_subprocess(_args(tmp_path, path, services, "shared", f"w{i}"), cwd=tmp_path) for i in range(2)]
    outputs = [_finish(w) for w in workers]
    for w, out in zip(workers, outputs):
        assert w.returncode == 0, out[-3000:]
        assert "Traceback" not in out, out[-3000:]

    study = optuna.load_study(study_name="shared", storage=db)
    trials = study.get_trials(deepcopy=False)
    assert [t.state.name for t in trials] == ["COMPLETE"] * 4  # the budget reached, nothing lost or beyond it
    assert [t.number for t in trials] == [0, 1, 2, 3]
    assert study.user_attrs["mlflow_tracking_uri"] == server  # the study names the server, not a local store

    parents, children = _runs(server, "shared")
    assert len(parents) == 1, [p.info.run_name for p in parents]  # one MLflow run per study, on the server
    (parent,) = parents
    assert parent.info.run_id == study.user_attrs["mlflow_parent_run_id"]
    assert parent.data.tags["optuna_storage"] == db and parent.info.status == "FINISHED"
    assert sorted(int(r.data.tags["optuna_trial"]) for r in children) == [0, 1, 2, 3]  # each trial run once
    assert {r.data.tags["mlflow.parentRunId"] for r in children} == {parent.info.run_id}
    assert all(r.info.status == "FINISHED" and r.data.tags["optuna_state"] == "COMPLETE" for r in children)
    # every trial's run is the one its trial recorded
    assert {t.user_attrs["run_ids"][0] for t in trials} == {r.info.run_id for r in children}
    # the trials' models went through the server's artefact proxy
    client = MlflowClient(server)
    assert all(client.list_artifacts(r.info.run_id) for r in children)


def test_a_killed_worker_of_another_machine_is_failed_by_its_heartbeats(services, tmp_path):
    db, server = services
    path = write_sweep(tmp_path, name="lost", n_trials=1, timesteps=10_000_000, eval_every=0)
    lost = _other_machine(_args(tmp_path, path, services, "lost", "lost"), cwd=tmp_path)
    _wait_for_training(lost)
    lost.kill()  # SIGKILL: no handler runs, no more heartbeats
    lost.wait(timeout=60)
    killed_at = time.monotonic()

    study = optuna.load_study(study_name="lost", storage=db)
    (trial,) = study.get_trials(deepcopy=False)
    assert trial.state.name == "RUNNING" and trial.user_attrs["worker"].startswith(f"{OTHER_HOST}:")
    _, (dead_run,) = _runs(server, "lost")
    assert dead_run.info.status == "RUNNING"  # as the killed worker left it

    time.sleep(max(0.0, killed_at + 2 * HEARTBEAT_S + 1 - time.monotonic()))  # the grace period is over
    # the dead trial holds the study's only slot: the worker must fail it, not find the budget spent
    here = run_subprocess(
        _args(tmp_path, path, services, "lost", "here", "sweep.timesteps=128", "sweep.eval_every=128"), tmp_path
    )
    out = _finish(here)
    assert here.returncode == 0, out[-3000:]
    assert "Traceback" not in out and "left RUNNING by a killed worker" in out, out[-3000:]

    study = optuna.load_study(study_name="lost", storage=db)
    trials = study.get_trials(deepcopy=False)
    assert [t.state.name for t in trials] == ["FAIL", "COMPLETE"]  # the dead trial's slot was run again
    assert "error" not in trials[0].user_attrs  # not the trial's own failure: it does not count
    assert trials[1].user_attrs["worker"].startswith(f"{socket.gethostname()}:")
    parents, children = _runs(server, "lost")
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"
    statuses = {int(r.data.tags["optuna_trial"]): r.info.status for r in children}
    assert statuses == {0: "KILLED", 1: "FINISHED"}  # the dead trial's run is not left RUNNING
