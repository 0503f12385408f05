"""One comparison end to end: query, group, aggregate, curves, pairs -- and the files ``python -m diana_lab.compare``
writes (``runs.csv``/``.md``, ``groups.csv``/``.md``, ``paired.csv``/``.md`` with a baseline,
``curves_<metric>.png``, ``final_metrics.png``).

:func:`compare_runs` is what notebooks call (everything in memory, as pandas); :func:`write_report` is the
CLI's second half. CSVs keep full precision and full run ids (``policy=<run id>`` evaluates one); the
Markdown tables are for reading and pasting into an issue.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from diana_lab.comparison.groups import (
    aggregate,
    assign_groups,
    learning_curves,
    repeated_seeds,
    runs_table,
    unfinished_runs,
)
from diana_lab.comparison.paired import empty, mixed_host_groups, paired_differences, resolve_baseline
from diana_lab.comparison.plots import plot_final_metrics, plot_learning_curves, save_figure
from diana_lab.comparison.runs import ComparisonError, load_runs, metric_histories
from diana_lab.tracking.host import HOST_TAG

__all__ = ["DEFAULT_CURVES", "DEFAULT_GROUP_BY", "DEFAULT_METRICS", "Comparison", "compare_runs", "write_report"]

DEFAULT_METRICS = (
    "eval_success_rate",
    "eval_spl",
    "eval_collision_rate",
    "eval_tipover_rate",
    "eval_timeout_rate",
    "eval_mean_path_length_m",
    "eval_mean_max_tilt_deg",
)
DEFAULT_CURVES = ("eval_success_rate", "eval_spl")
DEFAULT_GROUP_BY = ("algo", "world", "robot", "sensor", "dynamics", "action_space", "reward")


@dataclass
class Comparison:
    """The selected runs and what was computed from them (all pandas, for notebooks)."""

    raw: pd.DataFrame  # mlflow.search_runs' frame, with the group columns added
    runs: pd.DataFrame  # one row per run: options, seed, group, metrics
    groups: pd.DataFrame  # one row per group: runs, seeds, <metric>_mean / _std
    curves: pd.DataFrame  # metric, group, step, mean, std, n
    group_by: tuple[str, ...]
    metrics: tuple[str, ...]
    curve_metrics: tuple[str, ...]
    missing_metrics: dict[str, list[str]] = field(default_factory=dict)  # not logged by any run -> close names
    skipped: list[str] = field(default_factory=list)  # names of matching runs without any of the metrics
    repeated_seeds: dict[str, list[str]] = field(default_factory=dict)  # group -> seeds two of its runs share
    unfinished: dict[str, list[str]] = field(default_factory=dict)  # group -> its runs that did not finish
    mixed_hosts: dict[str, list[str]] = field(default_factory=dict)  # group -> the kinds of CPU its runs trained on
    baseline: str = ""  # the group the others are paired against ("": no paired table)
    paired: pd.DataFrame = field(default_factory=empty)  # per group and metric, against the baseline by seed


def _missing(raw: pd.DataFrame, wanted: Sequence[str]) -> dict[str, list[str]]:
    """Metrics no selected run logged (likely a typo), each with the closest names that do exist."""
    logged = sorted(c[len("metrics.") :] for c in raw.columns if c.startswith("metrics.") and raw[c].notna().any())
    return {m: difflib.get_close_matches(m, logged, n=3) for m in wanted if m not in logged}


def compare_runs(
    uri: str,
    experiments: Sequence[str],
    filter_string: str = "",
    metrics: Sequence[str] = DEFAULT_METRICS,
    curves: Sequence[str] = DEFAULT_CURVES,
    group_by: Sequence[str] = DEFAULT_GROUP_BY,
    variants: bool = True,
    include_evaluations: bool = False,
    baseline: str = "",
) -> Comparison:
    """Load the runs matching ``filter_string`` and compare them (see :mod:`diana_lab.comparison.groups`); with
    ``baseline`` (a group's label, a part of exactly one, or one of its runs' ids), also every other group against
    it, paired by seed (:mod:`diana_lab.comparison.paired`)."""
    group_by, metrics, curves = tuple(group_by), tuple(metrics), tuple(curves)
    found = load_runs(uri, experiments, filter_string, include_evaluations)
    _check_group_by(found, group_by)
    found, skipped = _with_metrics(found, (*metrics, *curves), filter_string)
    raw = assign_groups(found, group_by, variants)
    table = runs_table(raw, group_by, metrics)
    base = resolve_baseline(table, baseline) if baseline else ""
    histories = metric_histories(uri, list(raw["run_id"]), curves)
    curve_frame = learning_curves(histories, raw.set_index("run_id")["group"])
    return Comparison(
        raw=raw,
        runs=table,
        groups=aggregate(table, group_by, metrics),
        curves=curve_frame,
        group_by=group_by,
        metrics=metrics,
        curve_metrics=curves,
        missing_metrics=_missing(raw, (*metrics, *curves)),
        skipped=skipped,
        repeated_seeds=repeated_seeds(table),
        unfinished=unfinished_runs(table),
        mixed_hosts=mixed_host_groups(table),
        baseline=base,
        paired=paired_differences(table, base, metrics) if base else empty(),
    )


def _check_group_by(df: pd.DataFrame, group_by: Sequence[str]) -> None:
    """A ``group_by`` name that no selected run is tagged with (a typo, a config key) would put every run in one
    group without a word. Option groups are exempt: runs logged before their tag existed, or without a preset
    (``experiment``), lack it and rightly share the empty option."""
    tags = sorted(c[len("tags.") :] for c in df.columns if c.startswith("tags.") and df[c].notna().any())
    unknown = [g for g in group_by if g not in tags]
    if not unknown:
        return
    from diana_lab.tracking.names import TAG_GROUPS

    unknown = [g for g in unknown if g not in TAG_GROUPS]
    if unknown:
        params = [g for g in unknown if f"params.{g}" in df]
        hint = f" ({', '.join(params)}: config values, not tags; variants=true splits groups by them)" if params else ""
        available = ", ".join(t for t in tags if "." not in t)  # not MLflow's bookkeeping (mlflow.runName, ...)
        raise ComparisonError(
            f"group_by={list(group_by)}: no selected run has the tag(s) {', '.join(unknown)}{hint}; "
            f"the tags of these runs: {available or 'none'}"
        )


def _with_metrics(df: pd.DataFrame, wanted: Sequence[str], filter_string: str) -> tuple[pd.DataFrame, list[str]]:
    """Leave out runs that logged none of ``wanted`` -- a sweep's parent run, a run that failed before its
    first evaluation -- which would only be empty rows; their names are returned for a note."""
    cols = [f"metrics.{m}" for m in wanted if f"metrics.{m}" in df]
    keep = df[cols].notna().any(axis=1) if cols else pd.Series(False, index=df.index)
    if not keep.any():
        raise ComparisonError(
            f"filter={filter_string!r}: {len(df)} run(s) match but none logged any of {', '.join(wanted)}"
        )
    names = df.get("tags.mlflow.runName", df["run_id"]).fillna("")
    return df[keep].reset_index(drop=True), [str(n) for n in names[~keep]]


def _mean_std(mean: float, std: float) -> str:
    if not math.isfinite(mean):
        return "-"
    return f"{mean:.3f}" if not math.isfinite(std) else f"{mean:.3f} ± {std:.3f}"


def groups_markdown(c: Comparison) -> str:
    """The aggregated table with ``mean ± std`` cells (options that are equal for every group left out)."""
    view = pd.DataFrame({"group": c.groups["group"], "runs": c.groups["runs"], "seeds": c.groups["seeds"]})
    for m in c.metrics:
        view[m] = [_mean_std(a, b) for a, b in zip(c.groups[f"{m}_mean"], c.groups[f"{m}_std"])]
    return view.to_markdown(index=False, disable_numparse=True)


def paired_markdown(c: Comparison) -> str:
    """The paired table: per group and metric, the mean difference to the baseline with its 95 % interval."""
    p = c.paired
    view = pd.DataFrame(
        {
            "group": p["group"],
            "metric": p["metric"],
            "pairs": p["pairs"],
            "seeds": p["seeds"],
            "baseline": [_number(x) for x in p["baseline_mean"]],
            "group mean": [_number(x) for x in p["group_mean"]],
            "difference": [_number(x, signed=True) for x in p["diff_mean"]],
            "95 % interval": [_interval(lo, hi) for lo, hi in zip(p["ci95_low"], p["ci95_high"], strict=True)],
            "t": [_number(x, digits=2) for x in p["t"]],
            "p (two-sided)": [_number(x) for x in p["p_two_sided"]],
            "hosts": p["hosts"],
        }
    )
    return view.to_markdown(index=False, disable_numparse=True)


def _interval(low: float, high: float) -> str:
    return "-" if not math.isfinite(low) else f"{low:+.3f} .. {high:+.3f}"


def _number(x: float, signed: bool = False, digits: int = 3) -> str:
    if not math.isfinite(x):
        return "-"
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def runs_markdown(c: Comparison) -> str:
    view = c.runs.copy()
    view["run_id"] = view["run_id"].str[:8]
    constant = [g for g in c.group_by if view[g].nunique() <= 1]
    unused = [k for k in ("variant", HOST_TAG) if (view[k] == "").all()]
    view = view.drop(columns=[*constant, *unused])
    return view.to_markdown(index=False, floatfmt=".3f")


def write_report(c: Comparison, output: Path) -> list[Path]:
    """Write the tables and plots into ``output``; the paths written."""
    output.mkdir(parents=True, exist_ok=True)
    files = [output / "runs.csv", output / "runs.md", output / "groups.csv", output / "groups.md"]
    c.runs.to_csv(files[0], index=False)
    files[1].write_text(runs_markdown(c) + "\n")
    c.groups.to_csv(files[2], index=False)
    files[3].write_text(groups_markdown(c) + "\n")
    if c.baseline:
        files += [output / "paired.csv", output / "paired.md"]
        c.paired.to_csv(files[-2], index=False)
        files[-1].write_text(f"Against the baseline group {c.baseline!r}, paired by seed:\n\n{paired_markdown(c)}\n")
    for metric in c.curve_metrics:
        files.append(
            save_figure(plot_learning_curves(c.curves, metric), output / f"curves_{metric.replace('/', '_')}.png")
        )
    if any(f"{m}_mean" in c.groups for m in c.metrics):
        files.append(save_figure(plot_final_metrics(c.groups, c.metrics), output / "final_metrics.png"))
    return files
