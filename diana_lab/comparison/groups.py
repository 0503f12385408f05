"""Which runs are repeats of one experiment, and their statistics over seeds.

Runs form one group when they chose the same options of the ``group_by`` groups (their tags) and -- with
``variants`` -- also agree on every other config value except the seed and bookkeeping (``params.*``; e.g.
two PPO runs with different ``algo.learning_rate`` are two groups, labelled by the values that differ).
That is the "differ only in ``seed``" rule without the user listing every key a sweep may have changed. A key
a run never logged counts as a null one, so runs from before a new opt-in key (null by default) group with
those after it.
Group labels name only what differs between the groups of the selection, so plots stay readable.
"""

from __future__ import annotations

import fnmatch
import warnings
from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd

from diana_lab.comparison.runs import tag
from diana_lab.tracking.host import HOST_TAG

__all__ = [
    "IGNORED_PARAMS",
    "aggregate",
    "assign_groups",
    "in_seed_order",
    "learning_curves",
    "repeated_seeds",
    "runs_table",
    "unfinished_runs",
]

# params that do not change what is learnt (or are the seed): never a reason to split a group
IGNORED_PARAMS = (
    "seed",
    "tracking.*",
    "train.resume",
    "train.progress_bar",
    "train.device",
    "train.torch_threads",
    "train.vec_env",
    "train.checkpoint_every",
    "train.log_interval",
    "train.final_eval",
    "eval.video",
    "eval.plots",
)
MAX_LABEL_ITEMS = 3  # params named in a variant label before "+N more"
MAX_VALUE_CHARS = 24
UNSET = "unset"  # a label's word for a key a run did not log or logged as null (a blank read as a typo)


def _param_columns(df: pd.DataFrame) -> list[str]:
    keys = [c[len("params.") :] for c in df.columns if c.startswith("params.")]
    return [f"params.{k}" for k in keys if not any(fnmatch.fnmatchcase(k, p) for p in IGNORED_PARAMS)]


def _short(value: str) -> str:
    return value if len(value) <= MAX_VALUE_CHARS else value[: MAX_VALUE_CHARS - 1] + "…"


def _label(row: pd.Series, columns: Sequence[str]) -> str:
    items = [f"{c[len('params.') :]}={_short(row[c]) or UNSET}" for c in columns[:MAX_LABEL_ITEMS]]
    extra = len(columns) - MAX_LABEL_ITEMS
    return ", ".join(items) + (f" +{extra} more" if extra > 0 else "")


def _variant_labels(block: pd.DataFrame, columns: list[str]) -> pd.Series:
    """Within runs of the same options, a label of the config values that differ ("" when none do), one label
    per distinct set of values: runs are grouped by their labels, so two configs must never share one.

    A label names at most ``MAX_LABEL_ITEMS`` values, each cut to ``MAX_VALUE_CHARS``; configs that differ only
    beyond that are labelled again by the values that tell *them* apart, and numbered if even those do not."""
    # a key a run did not log (it predates the key) and one logged as null are the same: no value, so a new opt-in
    # key whose default is null does not split the runs made before it from those made after
    values = block[columns].fillna("").astype(str).replace("None", "")
    varying = [c for c in columns if values[c].nunique() > 1]
    if not varying:
        return pd.Series([""] * len(block), index=block.index, dtype=object)
    keys = values[varying].apply(tuple, axis=1)  # the whole config difference: what makes a group
    labels = values.apply(_label, axis=1, columns=varying)
    for shared in labels[labels.duplicated(keep=False)].unique():
        same = labels == shared
        group_keys = keys[same]
        if group_keys.nunique() < 2:
            continue
        telling = [c for c in varying if values.loc[same, c].nunique() > 1]
        new = pd.Series({i: f"{shared} | {_label(values.loc[i], telling)}" for i in group_keys.index}, dtype=object)
        for text in new[new.duplicated(keep=False)].unique():  # still shared by configs (values cut short)
            clash = new == text
            if group_keys[clash].nunique() > 1:
                for n, key in enumerate(dict.fromkeys(group_keys[clash]), start=1):
                    new[clash & (group_keys == key)] = f"{text} (#{n})"
        labels[same] = new
    return labels


def assign_groups(df: pd.DataFrame, group_by: Sequence[str], variants: bool = True) -> pd.DataFrame:
    """A copy of ``df`` (from :func:`~diana_lab.comparison.runs.load_runs`) with the columns ``seed``,
    ``variant`` (config differences beyond ``group_by``; "" without ``variants``), ``group`` (a readable
    label, unique per group) and one column per ``group_by`` tag."""
    out = df.copy()
    for g in group_by:
        out[g] = tag(out, g)
    out["seed"] = tag(out, "seed")
    out["variant"] = ""
    params = _param_columns(out)
    if variants and params:
        blocks = [b for _, b in out.groupby(list(group_by), sort=False)] if group_by else [out]
        for block in blocks:
            out.loc[block.index, "variant"] = _variant_labels(block, params)
    shown = [g for g in group_by if out[g].nunique() > 1]

    def label(row: pd.Series) -> str:
        parts = [f"{g}={row[g]}" for g in shown]
        if row["variant"]:
            parts.append(str(row["variant"]))
        return " / ".join(parts)

    out["group"] = out.apply(label, axis=1) if len(out) else pd.Series(dtype=object)
    if len(out) and (out["group"] == "").all():  # everything alike: name it by its options
        out["group"] = " / ".join(str(out[g].iloc[0]) for g in group_by if out[g].iloc[0]) or "all runs"
    return out


def _metric_column(metric: str) -> str:
    return f"metrics.{metric}"


def runs_table(grouped: pd.DataFrame, group_by: Sequence[str], metrics: Sequence[str]) -> pd.DataFrame:
    """One row per run: id, name, status, group, chosen options, seed, the CPU it trained on ("" where not
    tagged), then the metrics (NaN if not logged)."""
    table = pd.DataFrame(
        {
            "run_id": grouped["run_id"],
            "run_name": tag(grouped, "mlflow.runName"),
            "status": grouped.get("status", ""),
            "group": grouped["group"],
            **{g: grouped[g] for g in group_by},
            "variant": grouped["variant"],
            "seed": grouped["seed"],
            HOST_TAG: tag(grouped, HOST_TAG),
        }
    )
    for m in metrics:
        col = _metric_column(m)
        table[m] = grouped[col].astype(float) if col in grouped else np.nan
    return table.reset_index(drop=True)


def _seeds(block: pd.DataFrame) -> pd.Series:
    """The runs' seeds as shown: ``"?"`` for a run without the seed tag."""
    return block["seed"].astype(str).replace("", "?")


def in_seed_order(seeds: Iterable[str]) -> list[str]:
    return sorted(seeds, key=lambda s: (len(s), s))  # numerically for the integers they are: 2 before 10


def aggregate(table: pd.DataFrame, group_by: Sequence[str], metrics: Sequence[str]) -> pd.DataFrame:
    """Per group of :func:`runs_table`: ``runs``, ``seeds`` and each metric's ``<m>_mean`` / ``<m>_std``
    (sample standard deviation over the runs; NaN for a single run)."""
    rows = []
    for name, block in table.groupby("group", sort=False):
        row: dict[str, object] = {"group": name}
        row.update({g: block[g].iloc[0] for g in group_by})
        row["variant"] = block["variant"].iloc[0]
        row["runs"] = len(block)
        row["seeds"] = ",".join(in_seed_order(_seeds(block)))
        for m in metrics:
            values = block[m].astype(float)
            row[f"{m}_mean"] = values.mean()
            row[f"{m}_std"] = values.std(ddof=1) if values.notna().sum() > 1 else np.nan
        rows.append(row)
    return pd.DataFrame(rows)


def repeated_seeds(table: pd.DataFrame) -> dict[str, list[str]]:
    """Groups of :func:`runs_table` in which two or more runs share a seed (or lack the seed tag: ``"?"``), with
    those seeds. Such runs repeat one result rather than sample the seeds (a re-run, a resumed run logged twice),
    so the group's std is not a spread over seeds."""
    out: dict[str, list[str]] = {}
    for name, block in table.groupby("group", sort=False):
        counts = _seeds(block).value_counts()
        repeated = in_seed_order(counts.index[counts > 1])
        if repeated:
            out[str(name)] = repeated
    return out


def unfinished_runs(table: pd.DataFrame) -> dict[str, list[str]]:
    """Groups of :func:`runs_table` holding runs whose MLflow status is not ``FINISHED`` (still running, killed,
    failed), with those runs' names (their id where unnamed) and status. Their metrics are whatever they had
    logged when they stopped (a periodic evaluation, not the final one), yet they count in the group's mean."""
    out: dict[str, list[str]] = {}
    status = table["status"].fillna("").astype(str) if "status" in table else pd.Series("", index=table.index)
    for name, block in table[status != "FINISHED"].groupby("group", sort=False):
        names = block["run_name"] if "run_name" in block else block["run_id"]
        out[str(name)] = [
            f"{n or rid} ({st or 'no status'})"
            for n, rid, st in zip(names, block["run_id"], status[block.index], strict=True)
        ]
    return out


def learning_curves(histories: pd.DataFrame, groups: pd.Series) -> pd.DataFrame:
    """Mean and spread over the runs of each group at every step any of them was evaluated.

    ``histories`` is :func:`~diana_lab.comparison.runs.metric_histories`' frame, ``groups`` maps run id to
    group label. Runs of one group evaluated at slightly different steps are linearly interpolated onto
    the union of their steps, never extrapolated (a run counts only inside its own step range).
    Columns: ``metric``, ``group``, ``step``, ``mean``, ``std`` (NaN below two runs), ``n``.
    """
    rows: list[dict[str, object]] = []
    hist = histories.assign(group=histories["run_id"].map(groups))
    for (metric, group), block in hist.dropna(subset=["group"]).groupby(["metric", "group"], sort=False):
        steps = np.unique(block["step"].to_numpy())
        curves = []
        for _, run in block.groupby("run_id"):
            x, y = run["step"].to_numpy(dtype=float), run["value"].to_numpy(dtype=float)
            curve = np.interp(steps, x, y)
            curve[(steps < x.min()) | (steps > x.max())] = np.nan
            curves.append(curve)
        stack = np.vstack(curves)
        n = np.isfinite(stack).sum(axis=0)
        with warnings.catch_warnings():  # all-NaN columns cannot occur, one-run columns are masked below
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(stack, axis=0)
            std = np.where(n > 1, np.nanstd(stack, axis=0, ddof=1), np.nan)
        rows.extend(
            {"metric": metric, "group": group, "step": int(s), "mean": m, "std": sd, "n": int(k)}
            for s, m, sd, k in zip(steps, mean, std, n)
        )
    return pd.DataFrame(rows, columns=["metric", "group", "step", "mean", "std", "n"])
