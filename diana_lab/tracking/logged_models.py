"""Log an MLflow model (any flavour) to a given run, whatever run is active in the process.

MLflow 3's ``<flavour>.log_model`` logs to the active run, and creates the model (a ``LoggedModel``) in the
active run's experiment, else in the active or default experiment. The runner keeps explicit run ids
(:class:`~diana_lab.tracking.mlflow_run.MlflowTracker`) and the export logs to a finished training run with no run
active, so :func:`log_model_to_run` creates the model in the run's own experiment first and hands its id to
``Model.log``: ``runs:/<run id>/<name>`` then finds it (MLflow looks for a model of that name among the run's
experiment's models whose source run is the run).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Any

__all__ = ["log_model_to_run", "no_artifact_bars"]

ARTIFACT_BARS = "MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR"


@contextlib.contextmanager
def no_artifact_bars() -> Iterator[None]:
    """Without MLflow's "Downloading artifacts" bars, which ``Model.log`` draws when it loads the model back to
    check its input example: on a terminal they flash past, in a job's log file (``nohup``, a cluster) they are
    lines of carriage returns among the run's plain progress lines. The user's own setting is restored after."""
    saved = os.environ.get(ARTIFACT_BARS)
    os.environ[ARTIFACT_BARS] = "false"
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(ARTIFACT_BARS, None)
        else:
            os.environ[ARTIFACT_BARS] = saved


def log_model_to_run(uri: str, run_id: str, name: str, flavor: Any, **kwargs: Any) -> Any:
    """``Model.log`` of ``flavor`` (``mlflow.pyfunc``, ``mlflow.onnx``...) as the model ``name`` of run ``run_id``
    in the store at ``uri``; ``kwargs`` go to the flavour's ``save_model`` (and ``registered_model_name``,
    ``metadata``... to ``Model.log``). Returns MLflow's ``ModelInfo``."""
    import mlflow
    from mlflow.models import Model
    from mlflow.tracking import MlflowClient

    from diana_lab.tracking.atomic import uninterrupted

    with uninterrupted(), no_artifact_bars():  # Ctrl-C waits: a half-written model would be left PENDING
        mlflow.set_tracking_uri(uri)
        experiment_id = MlflowClient(uri).get_run(run_id).info.experiment_id
        model = mlflow.initialize_logged_model(name=name, source_run_id=run_id, experiment_id=experiment_id)
        return Model.log(None, flavor, name=name, run_id=run_id, model_id=model.model_id, **kwargs)
