"""The MLflow side of a study: one parent run, every trial's run nested under it.

The parent run is created through ``MlflowClient`` (never the fluent "active run"), so the runner can still
``mlflow.start_run`` each trial's run with ``parent_run_id`` in the same process. Its id is stored in the
study (user attribute ``mlflow_parent_run_id``): a rerun or a second worker reopens the same parent run, and
only the worker that created the study creates it (the others wait for it), so there is one per study.

MLflow params cannot change once logged, and a study's best trial does: the parent logs the search space as
params, and the best trial's params as ``best.<key>`` tags and ``best_params.json``; numbers that change as the
study runs (best value, the best trial's evaluation, trial counts) are metrics at step = finished trials.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from diana_lab.tracking.atomic import uninterrupted
from diana_lab.tracking.mlflow_run import MAX_TAG, resolve_uri, sqlite_path
from diana_lab.tracking.names import EXPERIMENT_TAGS
from diana_lab.tracking.params import truncate

__all__ = ["PARENT_ATTR", "TRACKING_ATTR", "ParentRun", "SweepClient"]

PARENT_ATTR = "mlflow_parent_run_id"
TRACKING_ATTR = "mlflow_tracking_uri"  # the store the parent run lives in: every worker must use it


class SweepClient:
    """An ``MlflowClient`` on the tracking store, with the writes the sweep needs, each uninterrupted."""

    def __init__(self, uri: str, experiment: str) -> None:
        from mlflow.tracking import MlflowClient

        from diana_lab.tracking.mlflow_run import _quiet_mlflow

        _quiet_mlflow()
        self.uri = resolve_uri(uri)
        self.client = MlflowClient(self.uri)
        self.experiment = experiment

    @uninterrupted()
    def experiment_id(self) -> str:
        found = self.client.get_experiment_by_name(self.experiment)
        if found is not None:
            return found.experiment_id
        db = sqlite_path(self.uri)
        location = (db.parent / "mlruns").as_uri() if db is not None else None
        try:
            return self.client.create_experiment(self.experiment, artifact_location=location, tags=EXPERIMENT_TAGS)
        except Exception:  # created meanwhile by another worker
            found = self.client.get_experiment_by_name(self.experiment)
            if found is None:
                raise
            return found.experiment_id

    @uninterrupted()
    def create_run(self, name: str, tags: Mapping[str, Any], parent_run_id: str | None = None) -> str:
        all_tags = {k: truncate(str(v), MAX_TAG) for k, v in tags.items() if v is not None}
        if parent_run_id:
            all_tags["mlflow.parentRunId"] = parent_run_id
        run = self.client.create_run(self.experiment_id(), tags=all_tags, run_name=name)
        return run.info.run_id

    @uninterrupted()
    def exists(self, run_id: str) -> bool:
        try:
            run = self.client.get_run(run_id)
        except Exception:
            return False
        return run.info.lifecycle_stage == "active"

    @uninterrupted()
    def set_status(self, run_id: str, status: str) -> None:
        if status == "RUNNING":
            self.client.update_run(run_id, status="RUNNING")
        else:
            self.client.set_terminated(run_id, status=status)

    @uninterrupted()
    def status(self, run_id: str) -> str:
        return self.client.get_run(run_id).info.status

    @uninterrupted()
    def set_tags(self, run_id: str, tags: Mapping[str, Any]) -> None:
        from mlflow.entities import RunTag

        items = {k: truncate(str(v), MAX_TAG) for k, v in tags.items() if v is not None}
        self.client.log_batch(run_id, tags=[RunTag(k, v) for k, v in items.items()])  # MLflow batches a long list

    @uninterrupted()
    def log_new_params(self, run_id: str, params: Mapping[str, Any]) -> None:
        """Params the run does not have yet (params are immutable: a rerun keeps the first values)."""
        from mlflow.entities import Param

        existing = self.client.get_run(run_id).data.params
        new = {k: truncate(str(v)) for k, v in params.items() if k not in existing}
        self.client.log_batch(run_id, params=[Param(k, v) for k, v in new.items()])

    @uninterrupted()
    def log_metrics(self, run_id: str, metrics: Mapping[str, float], step: int) -> None:
        import time

        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        items = [
            Metric(k, float(v), now, int(step))
            for k, v in metrics.items()
            if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        ]
        self.client.log_batch(run_id, metrics=items)

    @uninterrupted()
    def kill_running(self, study_name: str, trial_numbers: list[int]) -> list[str]:
        """End as KILLED the runs of these trials that a killed worker left RUNNING; their ids."""
        if not trial_numbers:
            return []
        found = self.client.search_runs(
            [self.experiment_id()],
            filter_string=f"tags.optuna_study = '{study_name}' and attributes.status = 'RUNNING'",
        )
        killed = [r.info.run_id for r in found if r.data.tags.get("optuna_trial") in {str(n) for n in trial_numbers}]
        for run_id in killed:
            self.client.set_terminated(run_id, status="KILLED")
        return killed

    @uninterrupted()
    def settle_trial_runs(self, study_name: str, trial_number: int, state: str) -> None:
        """Tag ``optuna_state`` on the runs of a trial that ended without one (it raised, or was interrupted)."""
        found = self.client.search_runs(
            [self.experiment_id()],
            filter_string=f"tags.optuna_study = '{study_name}' and tags.optuna_trial = '{trial_number}'",
        )
        for run in found:
            if "optuna_state" not in run.data.tags:
                self.client.set_tag(run.info.run_id, "optuna_state", state)

    @uninterrupted()
    def log_artifact(self, run_id: str, path: Path, artifact_path: str | None = None) -> None:
        self.client.log_artifact(run_id, str(path), artifact_path)

    @uninterrupted()
    def log_text(self, run_id: str, text: str, artifact_file: str) -> None:
        self.client.log_text(run_id, text, artifact_file)


class ParentRun:
    """The study's run: created once, reopened (RUNNING again) by every later worker, ended by each."""

    def __init__(self, client: SweepClient, run_id: str, created: bool) -> None:
        self.client, self.run_id, self.created = client, run_id, created

    @classmethod
    def open(cls, client: SweepClient, run_id: str | None, name: str, tags: Mapping[str, Any]) -> ParentRun:
        if run_id and client.exists(run_id):
            client.set_status(run_id, "RUNNING")
            client.set_tags(run_id, tags)
            return cls(client, run_id, created=False)
        return cls(client, client.create_run(name, tags), created=True)

    def end(self, status: str) -> None:
        self.client.set_status(self.run_id, status)

    def log_best(self, best: Mapping[str, Any], params: Mapping[str, Any], step: int) -> None:
        """The best trial so far: tags ``best.<key>``, metrics ``best_value`` and ``best_<summary key>``."""
        self.client.set_tags(
            self.run_id,
            {
                "best_trial": best["number"],
                "best_overrides": best.get("overrides"),
                "best_run_id": best.get("run_id"),
                **{f"best.{k}": v for k, v in params.items()},
            },
        )
        metrics = {"best_value": best["value"], **{f"best_{k}": v for k, v in best.get("summary", {}).items()}}
        self.client.log_metrics(self.run_id, metrics, step)
        self.client.log_text(self.run_id, json.dumps(dict(params), indent=2, default=str), "study/best_params.json")
