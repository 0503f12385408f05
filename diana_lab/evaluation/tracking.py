"""MLflow logging of an evaluation: ``eval_<key>`` metrics and the output files as artefacts.

Used by ``python -m diana_lab.evaluate`` when ``tracking.enabled`` is true: a policy from a training run is
logged as a child run of it (tag ``mlflow.parentRunId``, in the parent's experiment), any other policy as a
run of its own in ``tracking.experiment``. :func:`log_summary` logs into the active run, so the training
runner can use it for its own evaluations too. The metric names are the training runner's
(:mod:`diana_lab.tracking.names`), and the run is tagged with the options it was evaluated on (``world``,
``robot``, ``dynamics``, ``sensor``) and its parent's ``algo`` and ``seed``, so one MLflow filter
(``tags.algo = 'sac' and metrics.eval_spl > 0.8``) finds training runs and evaluations alike; the tag
``diana_lab.kind = evaluation`` tells them apart.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from diana_lab.tracking.host import HOST_TAG
from diana_lab.tracking.names import EVAL_PREFIX, EXPERIMENT_TAGS, eval_metrics

__all__ = ["log_evaluation", "log_summary", "metrics_of", "tracking_settings"]

DEFAULT_EXPERIMENT = "diana_lab"
PARENT_TAGS = ("algo", "seed", HOST_TAG)  # what the policy was trained as (and on), copied from the training run


def tracking_settings(cfg: DictConfig) -> tuple[bool, str | None, str]:
    """``(enabled, uri, experiment)`` from ``tracking.*`` (defaults when the keys are not in the config)."""
    enabled = bool(OmegaConf.select(cfg, "tracking.enabled", default=False))
    uri = OmegaConf.select(cfg, "tracking.uri", default=None)
    experiment = OmegaConf.select(cfg, "tracking.experiment", default=None) or DEFAULT_EXPERIMENT
    return enabled, (str(uri) if uri else None), str(experiment)


def metrics_of(summary: dict[str, Any], prefix: str = EVAL_PREFIX) -> dict[str, float]:
    """Finite numbers of a summary as metrics; ``<key>_ci95`` becomes ``<key>_ci95_lo`` / ``_hi``."""
    return eval_metrics(summary, prefix)


def log_summary(summary: dict[str, Any], prefix: str = EVAL_PREFIX, step: int | None = None) -> None:
    """Log a summary's metrics into the active MLflow run."""
    import mlflow

    mlflow.log_metrics(metrics_of(summary, prefix), step=step)


def log_evaluation(
    cfg: DictConfig,
    summaries: dict[str, dict[str, Any]],
    out_dir: Path,
    params: dict[str, Any],
    parent_run_id: str | None = None,
) -> str:
    """Log an evaluation run (metrics of every summary, every file of ``out_dir``); returns its run id.

    ``summaries`` maps a metric prefix (``eval_``, or ``eval_noise_0.5_`` in a sweep) to its summary.
    """
    import mlflow
    from mlflow.tracking import MlflowClient

    from diana_lab.tracking.mlflow_run import resolve_uri, sqlite_path

    _, uri, experiment = tracking_settings(cfg)
    if uri:
        mlflow.set_tracking_uri(resolve_uri(uri))
    client = MlflowClient()
    name = f"eval {params.get('policy', '')}".strip()
    if parent_run_id is not None:
        experiment_id = client.get_run(parent_run_id).info.experiment_id
        run = mlflow.start_run(experiment_id=experiment_id, parent_run_id=parent_run_id, run_name=name)
    else:
        found = client.get_experiment_by_name(experiment)
        if found is not None:
            experiment_id = found.experiment_id
        else:  # artefacts beside an SQLite store, as the training runs keep them
            db = sqlite_path(mlflow.get_tracking_uri())
            experiment_id = client.create_experiment(
                experiment,
                artifact_location=(db.parent / "mlruns").as_uri() if db is not None else None,
                tags=EXPERIMENT_TAGS,
            )
        run = mlflow.start_run(experiment_id=experiment_id, run_name=name)
    with run:
        mlflow.set_tags(_group_tags(client, params, parent_run_id))
        mlflow.log_params({k: str(v)[:500] for k, v in params.items()})
        for prefix, summary in summaries.items():
            log_summary(summary, prefix)
        for path in sorted(Path(out_dir).rglob("*")):
            if path.is_file() and path.suffix in (".csv", ".json", ".png", ".gif", ".yaml"):
                rel = path.parent.relative_to(out_dir)
                mlflow.log_artifact(str(path), artifact_path=None if str(rel) == "." else str(rel))
        return run.info.run_id


def _group_tags(client: Any, params: dict[str, Any], parent_run_id: str | None) -> dict[str, str]:
    """The evaluation run's tags: its kind, the env options it ran on, the parent's ``algo``, ``seed`` and
    ``host_cpu`` (the CPU that trained the weights, which is what a paired comparison must match)."""
    from diana_lab.tracking.names import TAG_GROUPS

    tags = {"diana_lab.kind": "evaluation"}
    if parent_run_id is not None:
        parent = client.get_run(parent_run_id).data.tags
        tags.update({k: parent[k] for k in PARENT_TAGS if k in parent})
    tags.update({k: str(v) for k, v in params.items() if k in TAG_GROUPS and v is not None})
    return tags
