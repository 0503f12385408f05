"""The MLflow dashboard, tried as a user would: ``mlflow server`` over a store of tiny runs, the experiment's
runs page in headless Chromium, filtered with ``metrics.eval_spl >= 0`` and showing the ``eval_*`` columns.

Chromium and chromedriver come from Debian (``./dev setup`` installs them); when they are missing or do not
start, the test fails with the reason instead of skipping. The screenshot is kept in the test's tmp folder
(its path is printed); ``python -m tests.dashboard.browser`` refreshes ``docs/img/mlflow_dashboard.png``.
"""

from __future__ import annotations

import pytest
from mlflow.tracking import MlflowClient

from tests.training.helpers import ALGO_TINY, TINY, run_in_process, store_args

from .browser import DashboardError, capture_runs_page, mlflow_server

COLUMNS = ["eval_success_rate", "eval_spl", "eval_mean_path_length_m", "eval_timeout_rate"]


@pytest.mark.slow
def test_experiment_page_lists_runs_with_their_eval_metrics(tmp_path):
    for algo in ("ppo", "a2c"):
        assert run_in_process([f"algo={algo}", *TINY, *ALGO_TINY[algo], *store_args(tmp_path, algo)]) == 0
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("diana_lab")
    runs = client.search_runs([exp.experiment_id])
    names = [r.info.run_name for r in runs]
    shot = tmp_path / "mlflow_dashboard.png"
    try:
        with mlflow_server(uri, tmp_path / "server.log") as url:
            text, rows = capture_runs_page(url, exp.experiment_id, names, COLUMNS, shot, tmp_path / "chrome")
    except DashboardError as exc:
        pytest.fail(f"dashboard: {exc}")
    print(f"dashboard screenshot: {shot}")
    assert shot.stat().st_size > 10_000
    assert "2 matching runs" in text
    assert all(c in text for c in COLUMNS)
    assert sorted(rows) == sorted(names), text
    for run in runs:  # the table shows each run's own latest values
        assert rows[run.info.run_name] == pytest.approx([run.data.metrics[c] for c in COLUMNS], rel=1e-6)
