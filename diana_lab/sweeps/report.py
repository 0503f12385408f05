"""What a study has found, for people: the table of top trials, the command that reproduces the best one,
the trials as CSV and Optuna's plots as HTML (for the parent MLflow run).

The reproduce line is the best trial's complete override line -- base overrides, the command line's,
the sampled params, the budget and the seeds -- shell-quoted, so pasting it trains the same configuration with
``python -m diana_lab`` (a multirun over the seeds when the study averaged several).
"""

from __future__ import annotations

import logging
import shlex
import warnings
from pathlib import Path
from typing import Any

import optuna
import pandas as pd
from optuna.trial import FrozenTrial, TrialState

from diana_lab.sweeps.objective import SUMMARY_ATTRS, TrialPlan
from diana_lab.sweeps.study import OVERRIDES_ATTR, SEEDS_ATTR

__all__ = ["best_trial", "counts", "reproduce_command", "top_table", "write_plots", "write_trials_csv"]

log = logging.getLogger(__name__)


def best_trial(study: optuna.Study) -> FrozenTrial | None:
    """The best COMPLETE trial, or ``None`` (``study.best_trial`` raises when there is none)."""
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not done:
        return None
    return study.best_trial


def counts(study: optuna.Study) -> dict[str, int]:
    out = {s.name.lower(): 0 for s in TrialState}
    for t in study.get_trials(deepcopy=False):
        out[t.state.name.lower()] += 1
    return out


def reproduce_command(plan: TrialPlan, trial: FrozenTrial) -> str:
    """``python -m diana_lab <base> <command line> <best params> <budget> seed=<seed>`` as the trial ran (its
    recorded override line: a rerun of the study with another budget does not change it); with several seeds a
    multirun over them (``-m ... seed=0,1``), since the trial's value was their mean."""
    recorded = trial.user_attrs.get(OVERRIDES_ATTR)
    if recorded is not None:
        base, seeds = [str(o) for o in recorded], [int(s) for s in trial.user_attrs.get(SEEDS_ATTR) or []]
    else:  # a trial from before the line was recorded: this worker's plan
        base = plan.overrides({p.key: trial.params[p.key] for p in plan.params if p.key in trial.params})
        seeds = list(plan.seeds)
    if len(seeds) > 1:
        overrides = ["-m", *base, f"seed={','.join(str(s) for s in seeds)}"]
    else:
        overrides = base + [f"seed={s}" for s in seeds]
    return "python -m diana_lab " + " ".join(shlex.quote(o) for o in overrides)


def _short_names(keys: list[str]) -> dict[str, str]:
    """Column names a terminal can hold: the keys without their common dotted prefix
    (``reward.terms.goal.weight`` -> ``goal.weight``, ``reward.terms.roll.params.deadband_deg`` ->
    ``roll.params.deadband_deg``)."""
    parts = [k.split(".") for k in keys]
    common = 0
    while parts and all(len(p) > common + 1 and p[common] == parts[0][common] for p in parts):
        common += 1
    return {k: ".".join(p[common:]) for k, p in zip(keys, parts)}


def top_table(study: optuna.Study, metric: str, n: int = 10) -> pd.DataFrame:
    """The ``n`` best finished trials (COMPLETE by value, then PRUNED by their last reported value)."""
    rows: list[dict[str, Any]] = []
    trials = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED))
    short = _short_names(sorted({k for t in trials for k in t.params}))
    for t in trials:
        value = t.value if t.value is not None else (t.intermediate_values.get(t.last_step) if t.last_step else None)
        row: dict[str, Any] = {"trial": t.number, "state": t.state.name, metric: value}
        row.update({k: t.user_attrs[k] for k in SUMMARY_ATTRS if k in t.user_attrs and k != metric})
        row.update({short[k]: v for k, v in t.params.items()})
        row["duration_s"] = round(t.duration.total_seconds(), 1) if t.duration else None
        rows.append(row)
    if not rows:
        return pd.DataFrame(columns=["trial", "state", metric])
    df = pd.DataFrame(rows)
    ascending = study.direction == optuna.study.StudyDirection.MINIMIZE
    df["_complete"] = df["state"] == "COMPLETE"
    df = df.sort_values(["_complete", metric], ascending=[False, ascending], na_position="last")
    return df.drop(columns="_complete").head(n).reset_index(drop=True)


def write_trials_csv(study: optuna.Study, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    study.trials_dataframe().to_csv(path, index=False)
    return path


def write_plots(study: optuna.Study, directory: Path) -> list[Path]:
    """Optimisation history, parameter importances and parallel coordinates as stand-alone HTML files.

    A plot that cannot be drawn yet (importances need two complete trials that differ) is skipped with a
    log line rather than failing the study's report.
    """
    from optuna import visualization as vis

    directory.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    plots = {
        "optimization_history": vis.plot_optimization_history,
        "param_importances": vis.plot_param_importances,
        "parallel_coordinate": vis.plot_parallel_coordinate,
    }
    for name, plot in plots.items():
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fig = plot(study)
            path = directory / f"{name}.html"
            fig.write_html(str(path), include_plotlyjs="cdn")  # ~10 kB, not 5 MB: plotly.js from its CDN
            written.append(path)
        except Exception as exc:  # too few trials, a single value per param, ...
            log.info("sweep report: no %s plot (%s)", name, exc)
    return written
