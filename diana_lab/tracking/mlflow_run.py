"""One MLflow run per training run, behind a small :class:`Tracker` interface.

:class:`Tracker` is the null object (``tracking.enabled=false``): the runner calls the same methods and
nothing is recorded. :class:`MlflowTracker` talks to the store through ``MlflowClient`` with an explicit run
id (no reliance on a thread's "active run"), starts runs with ``mlflow.start_run`` so MLflow adds its system
tags, and always ends them with an explicit status, so no run is left RUNNING.

A relative SQLite URI (the default ``sqlite:///mlflow.db``) is made absolute and the experiment's artefacts
are stored beside the database (``mlruns/``), so ``mlflow ui --backend-store-uri <uri>`` finds everything
whatever the working directory of a later process. Every store write is :func:`uninterrupted`: Ctrl-C waits
for it to finish instead of leaving SQLite locked.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any

from diana_lab.core.validation import ConfigError
from diana_lab.tracking.atomic import uninterrupted
from diana_lab.tracking.names import EXPERIMENT_TAGS
from diana_lab.tracking.params import flatten, truncate

__all__ = ["STATUSES", "MlflowTracker", "Tracker", "resolve_uri", "writable_store"]

STATUSES = ("FINISHED", "FAILED", "KILLED")
MAX_TAG = 8000  # mlflow.utils.validation.MAX_TAG_VAL_LENGTH
SQLITE = "sqlite:///"


def resolve_uri(uri: str) -> str:
    """``sqlite:///rel.db`` -> ``sqlite:////abs/rel.db`` (other URIs unchanged)."""
    if uri.startswith(SQLITE) and not uri.startswith(SQLITE + "/") and ":memory:" not in uri:
        return SQLITE + str(Path(uri[len(SQLITE) :]).expanduser().resolve())
    return uri


def sqlite_path(uri: str) -> Path | None:
    return Path(uri[len(SQLITE) :]) if uri.startswith(SQLITE + "/") else None


def writable_store(uri: str, key: str = "tracking.uri") -> str:
    """``uri`` resolved; for an SQLite store, its folder is created and checked writable now, so a place that
    cannot hold the database (a missing or read-only folder, a file in the way) fails with a message naming
    ``key`` instead of an ``OSError`` from deep inside MLflow -- or, for an evaluation, after the work. Any other
    store (a server, another database) must answer one query now, for the same reason."""
    resolved = resolve_uri(uri)
    db = sqlite_path(resolved)
    if db is None:
        _answers(resolved, key, uri)
        return resolved
    try:
        db.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        why = "a file is in the way" if isinstance(exc, FileExistsError | NotADirectoryError) else exc.strerror
        raise ConfigError(
            f"{key}={uri}: cannot create the folder '{db.parent}' for the SQLite store ({why or exc})"
        ) from exc
    target = db if db.exists() else db.parent
    if not os.access(target, os.W_OK):
        raise ConfigError(f"{key}={uri}: '{target}' is not writable; expected a writable SQLite store path")
    return resolved


def _answers(resolved: str, key: str, uri: str) -> None:
    """One query to a store that is not SQLite, without MLflow's minutes of HTTP retries: a server that is down or
    a database whose driver is not installed fails here, naming ``key``."""
    from mlflow.tracking import MlflowClient

    retries = os.environ.get("MLFLOW_HTTP_REQUEST_MAX_RETRIES")
    os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] = "0"
    try:
        MlflowClient(resolved).search_experiments(max_results=1)
    except Exception as exc:  # MlflowException, a missing driver (ImportError), a bad URI (ValueError)...
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(
            f"{key}={uri}: the tracking store does not answer ({type(exc).__name__}: {first[:300]}); expected "
            "sqlite:///<path>.db or the URI of a running MLflow server (mlflow server ...)"
        ) from exc
    finally:
        if retries is None:
            os.environ.pop("MLFLOW_HTTP_REQUEST_MAX_RETRIES", None)
        else:
            os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] = retries


def _quiet_mlflow() -> None:
    """MLflow and its migrations log at INFO on every new database; keep the console for training."""
    for name in ("mlflow", "alembic"):
        logging.getLogger(name).setLevel(logging.WARNING)


class Tracker:
    """No-op tracker (``tracking.enabled=false``); :class:`MlflowTracker` records the same calls."""

    run_id: str | None = None
    uri: str | None = None

    def existing_params(self) -> dict[str, str]:
        return {}

    def log_params(self, params: dict[str, Any]) -> None:
        pass

    def set_tags(self, tags: dict[str, Any]) -> None:
        pass

    def log_metrics(self, metrics: dict[str, float], step: int) -> None:
        pass

    def log_artifact(self, path: Path | str, artifact_path: str | None = None) -> None:
        pass

    def log_artifacts(self, directory: Path | str, artifact_path: str | None = None) -> None:
        pass

    def log_text(self, text: str, artifact_file: str) -> None:
        pass

    def end(self, status: str) -> None:
        pass


class MlflowTracker(Tracker):
    """Start (or, with ``resume_run_id``, reopen) a run in ``experiment`` of the store at ``uri``; a new run
    with ``parent_run_id`` is nested under that run (a sweep trial under its study's run)."""

    @uninterrupted()
    def __init__(
        self,
        uri: str,
        experiment: str,
        run_name: str | None = None,
        resume_run_id: str | None = None,
        parent_run_id: str | None = None,
    ) -> None:
        import mlflow
        from mlflow.exceptions import MlflowException
        from mlflow.tracking import MlflowClient

        _quiet_mlflow()
        self.uri = writable_store(uri)
        try:
            mlflow.set_tracking_uri(self.uri)
            self.client = MlflowClient(self.uri)
            if resume_run_id is not None:
                run = mlflow.start_run(run_id=resume_run_id)
            else:
                run = mlflow.start_run(
                    experiment_id=self._experiment_id(experiment), run_name=run_name, parent_run_id=parent_run_id
                )
        except (MlflowException, OSError) as exc:  # OSError: e.g. the disk is full or the database read-only
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ConfigError(f"tracking.uri={uri}: cannot open an MLflow run there ({first})") from exc
        self.run_id = run.info.run_id
        self.experiment_id = run.info.experiment_id
        self._ended = False

    def _experiment_id(self, name: str) -> str:
        found = self.client.get_experiment_by_name(name)
        if found is not None:
            return found.experiment_id
        db = sqlite_path(self.uri)
        location = (db.parent / "mlruns").as_uri() if db is not None else None
        try:
            return self.client.create_experiment(name, artifact_location=location, tags=EXPERIMENT_TAGS)
        except Exception:  # a parallel job of the same multirun (hydra/launcher=joblib) created it meanwhile
            found = self.client.get_experiment_by_name(name)
            if found is None:
                raise
            return found.experiment_id

    @uninterrupted()
    def existing_params(self) -> dict[str, str]:
        return dict(self.client.get_run(self.run_id).data.params)

    @uninterrupted()
    def log_params(self, params: dict[str, Any]) -> None:
        from mlflow.entities import Param

        # MlflowClient.log_batch splits a long list into the batches the store accepts
        self.client.log_batch(self.run_id, params=[Param(k, v) for k, v in flatten(params).items()])

    @uninterrupted()
    def set_tags(self, tags: dict[str, Any]) -> None:
        from mlflow.entities import RunTag

        items = {k: truncate(str(v), MAX_TAG) for k, v in tags.items() if v is not None}
        self.client.log_batch(self.run_id, tags=[RunTag(k, v) for k, v in items.items()])

    @uninterrupted()
    def log_metrics(self, metrics: dict[str, float], step: int) -> None:
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        self.client.log_batch(self.run_id, metrics=[Metric(k, float(v), now, int(step)) for k, v in metrics.items()])

    @uninterrupted()
    def log_artifact(self, path: Path | str, artifact_path: str | None = None) -> None:
        self.client.log_artifact(self.run_id, str(path), artifact_path)

    @uninterrupted()
    def log_artifacts(self, directory: Path | str, artifact_path: str | None = None) -> None:
        self.client.log_artifacts(self.run_id, str(directory), artifact_path)

    @uninterrupted()
    def log_text(self, text: str, artifact_file: str) -> None:
        self.client.log_text(self.run_id, text, artifact_file)

    @uninterrupted()
    def end(self, status: str) -> None:
        """End the run with ``status`` (FINISHED, FAILED or KILLED); safe to call twice."""
        import mlflow

        if self._ended:
            return
        self._ended = True
        active = mlflow.active_run()
        if active is not None and active.info.run_id == self.run_id:
            mlflow.end_run(status=status)
        else:
            self.client.set_terminated(self.run_id, status=status)
