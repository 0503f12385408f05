"""MLflow plumbing: param flattening within MLflow's limits, metric forwarding, run statuses."""

import math

import numpy as np
import pytest
from mlflow.tracking import MlflowClient

from diana_lab.tracking import MLflowOutputFormat, MlflowTracker, Tracker, resolve_uri
from diana_lab.tracking.params import MAX_VALUE, flatten, numeric_metrics


class Recorder(Tracker):
    def __init__(self):
        self.logged = []

    def log_metrics(self, metrics, step):
        self.logged.append((dict(metrics), step))


def test_flatten_joins_keys_and_truncates_long_values():
    flat = flatten(
        {
            "algo": {"lr": 0.1, "net_arch": [64, 64], "extractor": {"k": None}},
            "big": "x" * 10_000,
            "k" * 300: 1,
            "empty": {},
        }
    )
    assert flat["algo.lr"] == "0.1"
    assert flat["algo.net_arch"] == "[64, 64]"
    assert flat["algo.extractor.k"] == "None"
    assert len(flat["big"]) == MAX_VALUE and flat["big"].endswith("[truncated]")
    assert "k" * 300 not in flat  # over MLflow's key limit: skipped rather than failing the run
    assert flat["empty"] == "{}"


def test_numeric_metrics_expands_intervals_and_drops_nan():
    m = numeric_metrics(
        {"success_rate": 0.5, "success_rate_ci95": [0.2, 0.8], "spl": math.nan, "name": "x", "episodes": 10},
        "eval/",
    )
    assert m == {
        "eval/success_rate": 0.5,
        "eval/success_rate_ci95_lo": 0.2,
        "eval/success_rate_ci95_hi": 0.8,
        "eval/episodes": 10.0,
    }


def test_writer_forwards_scalars_only_and_honours_exclusion():
    rec = Recorder()
    MLflowOutputFormat(rec).write(
        {
            "rollout/ep_rew_mean": np.float32(1.5),
            "time/fps": 100,
            "eval/spl": 0.3,
            "note": "text",
            "train/nan": float("nan"),
            "flag": True,
        },
        {
            "rollout/ep_rew_mean": None,
            "time/fps": None,
            "eval/spl": ("mlflow",),
            "note": None,
            "train/nan": None,
            "flag": None,
        },
        step=42,
    )
    assert rec.logged == [({"rollout/ep_rew_mean": 1.5, "time/fps": 100.0}, 42)]


def test_relative_sqlite_uri_becomes_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_uri("sqlite:///mlflow.db") == f"sqlite:///{tmp_path}/mlflow.db"
    assert resolve_uri("sqlite:////abs/m.db") == "sqlite:////abs/m.db"
    assert resolve_uri("http://localhost:5000") == "http://localhost:5000"


@pytest.mark.parametrize("status", ["FINISHED", "KILLED"])
def test_tracker_logs_many_params_and_ends_with_status(tmp_path, status):
    uri = f"sqlite:///{tmp_path}/m.db"
    t = MlflowTracker(uri, "exp", run_name="r")
    t.log_params({"group": {f"k{i}": i for i in range(250)}, "long": "y" * 7000})  # > 100 per batch
    t.log_metrics({"a": 1.0}, step=5)
    (tmp_path / "f.txt").write_text("hi")
    t.log_artifact(tmp_path / "f.txt", "files")
    t.end(status)
    t.end("FAILED")  # a second end is ignored
    run = MlflowClient(uri).get_run(t.run_id)
    assert run.info.status == status
    assert len(run.data.params) == 251 and run.data.params["group.k7"] == "7"
    assert run.data.metrics == {"a": 1.0}
    assert [a.path for a in MlflowClient(uri).list_artifacts(t.run_id, "files")] == ["files/f.txt"]
    assert (tmp_path / "mlruns").is_dir()  # artefacts sit beside the database


def test_tracker_hands_long_lists_of_tags_and_metrics_to_mlflow_in_one_call(tmp_path):
    # MLflow's own log_batch splits them into the store's batches (100 tags, 1000 metrics)
    uri = f"sqlite:///{tmp_path}/m.db"
    t = MlflowTracker(uri, "exp")
    t.set_tags({f"t{i}": i for i in range(150)})
    t.log_metrics({f"m{i}": float(i) for i in range(1200)}, step=3)
    t.log_metrics({}, step=4)  # nothing to log is fine
    t.end("FINISHED")
    run = MlflowClient(uri).get_run(t.run_id)
    assert run.data.tags["t149"] == "149" and len([k for k in run.data.tags if k.startswith("t")]) == 150
    assert len(run.data.metrics) == 1200 and run.data.metrics["m1199"] == 1199.0


def test_experiments_the_platform_creates_are_tagged_for_model_development(tmp_path):
    from diana_lab.sweeps.mlflow_runs import SweepClient

    uri = f"sqlite:///{tmp_path}/m.db"
    MlflowTracker(uri, "train-exp").end("FINISHED")
    SweepClient(uri, "sweep-exp").experiment_id()
    client = MlflowClient(uri)
    for name in ("train-exp", "sweep-exp"):
        tags = client.get_experiment_by_name(name).tags
        assert tags.get("mlflow.experimentKind") == "custom_model_development", name


def test_tracker_reopens_a_run(tmp_path):
    uri = f"sqlite:///{tmp_path}/m.db"
    first = MlflowTracker(uri, "exp")
    first.log_params({"a": 1})
    first.end("KILLED")
    again = MlflowTracker(uri, "exp", resume_run_id=first.run_id)
    assert again.run_id == first.run_id and again.existing_params() == {"a": "1"}
    again.end("FINISHED")
    assert MlflowClient(uri).get_run(first.run_id).info.status == "FINISHED"


@pytest.mark.parametrize(
    ("uri", "named"),
    [("http://127.0.0.1:9", "MlflowException"), ("postgresql://u@127.0.0.1:9/db", "psycopg")],
)
def test_a_store_that_does_not_answer_is_a_config_error_naming_the_key(uri, named):
    """Checked before the work (an evaluation used to fail with a traceback after it), without MLflow's minutes
    of HTTP retries."""
    import os

    from diana_lab.config import ConfigError
    from diana_lab.tracking.mlflow_run import writable_store

    before = os.environ.get("MLFLOW_HTTP_REQUEST_MAX_RETRIES")
    with pytest.raises(ConfigError, match=rf"tracking\.uri={uri}: the tracking store does not answer.*{named}"):
        writable_store(uri)
    assert os.environ.get("MLFLOW_HTTP_REQUEST_MAX_RETRIES") == before  # put back
