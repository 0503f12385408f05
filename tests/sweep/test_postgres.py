"""A study in a real PostgreSQL server (what several machines share): started on loopback for the test.

If the server cannot be started the test fails with the reason: ``./dev setup`` installs Debian's postgresql.
"""

from __future__ import annotations

import contextlib

import optuna
import pytest

from .helpers import mlflow_runs, run_in_process, sweep_args, write_sweep
from .postgres import PostgresUnavailable, postgres_server


@pytest.mark.slow
def test_sweep_on_a_postgresql_storage(tmp_path):
    path = write_sweep(tmp_path, n_trials=2)
    with contextlib.ExitStack() as stack:
        try:
            url = stack.enter_context(postgres_server())
        except PostgresUnavailable as exc:
            pytest.fail(f"PostgreSQL could not be started: {exc}")
        assert run_in_process(sweep_args(tmp_path, path, f"sweep.storage={url}")) == 0
        study = optuna.load_study(study_name="tiny", storage=url)
        assert [t.state.name for t in study.trials] == ["COMPLETE", "COMPLETE"]
        _, (parent,), children = mlflow_runs(tmp_path)
        assert parent.data.tags["optuna_storage"] == url and len(children) == 2
        assert {r.data.tags["mlflow.parentRunId"] for r in children} == {parent.info.run_id}
        # a rerun loads the study from the server and finds its budget spent
        assert run_in_process(sweep_args(tmp_path, path, f"sweep.storage={url}", out="again")) == 0
        assert len(optuna.load_study(study_name="tiny", storage=url).trials) == 2
