"""Runs from an MLflow store as pandas: ``mlflow.search_runs`` for the runs, metric histories for curves.

The store is addressed by URI explicitly (the same ``tracking.uri`` the runs were logged with) and the
process-wide tracking URI is restored afterwards, so a notebook or a test can read several stores without
one query leaking into the next. Every mistake a user can make -- a store that does not exist, an unknown
experiment, a filter MLflow cannot parse, a filter that matches nothing -- raises :class:`ComparisonError`
(a ``ValueError``, so the CLI turns it into one paragraph and exit status 2) naming what to change.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence

import pandas as pd

from diana_lab.tracking.mlflow_run import resolve_uri, sqlite_path

__all__ = ["EVALUATION_KIND", "ComparisonError", "load_runs", "metric_histories", "tag", "using_store"]

EVALUATION_KIND = "evaluation"  # tag diana_lab.kind of the runs python -m diana_lab.evaluate logs


class ComparisonError(ValueError):
    """A comparison that cannot be made as asked (no store, no such experiment, bad or empty filter)."""


@contextlib.contextmanager
def using_store(uri: str) -> Iterator[str]:
    """Point ``mlflow`` at ``uri`` (made absolute) for the block; the previous tracking URI comes back after.

    An SQLite URI must name an existing file: MLflow would otherwise create an empty store and report
    "no runs", hiding a typo in the path.
    """
    import mlflow

    resolved = resolve_uri(uri)
    db = sqlite_path(resolved)
    if db is not None and not db.is_file():
        raise ComparisonError(
            f"tracking.uri={uri}: no MLflow store at {db} (train a run first, or pass tracking.uri=sqlite:///PATH)"
        )
    previous = mlflow.get_tracking_uri()
    mlflow.set_tracking_uri(resolved)
    try:
        yield resolved
    finally:
        mlflow.set_tracking_uri(previous)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def load_runs(
    uri: str,
    experiments: Sequence[str],
    filter_string: str = "",
    include_evaluations: bool = False,
) -> pd.DataFrame:
    """The runs of ``experiments`` matching ``filter_string`` (MLflow's search syntax), oldest first.

    One row per run with MLflow's columns: ``run_id``, ``status``, ``start_time``, ``metrics.<name>`` (the
    latest value), ``params.<key>`` (the resolved config) and ``tags.<name>`` (the chosen options:
    ``tags.algo``, ``tags.world``, ...; ``tags.seed``). Evaluation runs of ``python -m diana_lab.evaluate``
    carry the same metric names but no learning curve; they are left out unless ``include_evaluations``.
    Raises :class:`ComparisonError` when nothing matches, naming the filter.
    """
    import mlflow
    from mlflow.exceptions import MlflowException

    names = [str(e) for e in experiments]
    with using_store(uri) as resolved:
        client = mlflow.MlflowClient(resolved)
        missing = [e for e in names if client.get_experiment_by_name(e) is None]
        if missing:
            known = sorted(e.name for e in client.search_experiments())
            raise ComparisonError(
                f"experiments={missing}: no such experiment in {resolved} (known: {', '.join(known) or 'none'})"
            )
        try:
            df = mlflow.search_runs(experiment_names=names, filter_string=filter_string, order_by=["start_time ASC"])
        except MlflowException as exc:
            raise ComparisonError(f"filter={filter_string!r}: MLflow cannot use it ({_first_line(exc)})") from exc
    assert isinstance(df, pd.DataFrame)
    kind = df.get("tags.diana_lab.kind")
    if not include_evaluations and kind is not None:
        df = df[kind.fillna("") != EVALUATION_KIND]
    if df.empty:
        what = f"filter={filter_string!r}" if filter_string else "filter='' (all runs)"
        raise ComparisonError(
            f"{what}: no runs match in experiment(s) {', '.join(names)} of {resolved}"
            + ("" if include_evaluations else " (evaluation runs excluded)")
        )
    return df.reset_index(drop=True)


def tag(df: pd.DataFrame, name: str) -> pd.Series:
    """A tag column as strings ("" where a run lacks the tag), so grouping never drops rows on NaN."""
    col = f"tags.{name}"
    if col not in df:
        return pd.Series([""] * len(df), index=df.index, dtype=object)
    return df[col].fillna("").astype(str)


def metric_histories(uri: str, run_ids: Sequence[str], metrics: Sequence[str]) -> pd.DataFrame:
    """Every logged value of ``metrics`` for ``run_ids``: columns ``run_id``, ``metric``, ``step``, ``value``.

    Several values at one step (a periodic and the final evaluation both at the last step) keep the newest,
    which is also what MLflow shows as the run's metric.
    """
    import mlflow

    rows: list[tuple[str, str, int, float, int]] = []
    with using_store(uri) as resolved:
        client = mlflow.MlflowClient(resolved)
        for run_id in run_ids:
            for metric in metrics:
                rows.extend(
                    (run_id, metric, m.step, m.value, m.timestamp) for m in client.get_metric_history(run_id, metric)
                )
    df = pd.DataFrame(rows, columns=["run_id", "metric", "step", "value", "timestamp"])
    df = df.sort_values(["run_id", "metric", "step", "timestamp"]).drop_duplicates(
        ["run_id", "metric", "step"], keep="last"
    )
    return df.drop(columns="timestamp").reset_index(drop=True)
