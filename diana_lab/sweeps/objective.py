"""One trial: sample the search space, train once per seed with the runner, score on the fixed evaluation suite.

The objective is an evaluation metric (``spl`` by default) of the final evaluation on the seeded suite of
:mod:`diana_lab.evaluation` -- the same episodes for every trial -- never the shaped training return, which
changes with the very reward weights being searched. With several seeds it is the mean over seeds.

Pruning uses the runner's periodic evaluations: each summary's metric is reported to the trial at step =
training timesteps (seed ``i`` adds ``i`` x the trial's timesteps, so steps stay comparable between trials) and
a trial the pruner rejects stops through :class:`~diana_lab.training.StopRun`: its MLflow run ends KILLED and
Optuna records it PRUNED.

Failures are recorded, never fatal to the study: an exception marks the trial FAIL with its message in the
``error`` user attribute (the trial counts towards ``n_trials``); Ctrl-C / SIGTERM mark it FAIL with
``interrupted`` instead (it does not count, so a rerun repeats it) and stop the worker.
"""

from __future__ import annotations

import math
import statistics
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import optuna
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

from diana_lab.sweeps.compose import compose_run
from diana_lab.sweeps.mlflow_runs import SweepClient
from diana_lab.sweeps.space import Param, format_value
from diana_lab.sweeps.spec import BUDGET_KEYS, SweepSpec
from diana_lab.sweeps.study import ERROR_ATTR, INTERRUPTED_ATTR, OVERRIDES_ATTR, SEEDS_ATTR, WORKER_ATTR
from diana_lab.training.context import RunContext, StopRun
from diana_lab.training.signals import raise_pending

__all__ = ["SUMMARY_ATTRS", "Objective", "TrialPlan", "suggest"]

# evaluation summary keys kept on each trial (user attributes, so the study's table and CSV show them)
SUMMARY_ATTRS = (
    "success_rate",
    "spl",
    "collision_rate",
    "tipover_rate",
    "timeout_rate",
    "stuck_rate",
    "mean_path_length_m",
)


def suggest(trial: optuna.Trial, param: Param) -> Any:
    """Sample ``param`` through the public ``suggest_*`` API (so it works with every sampler and storage)."""
    d = param.distribution
    if isinstance(d, FloatDistribution):
        return trial.suggest_float(param.key, d.low, d.high, log=d.log, step=d.step)
    if isinstance(d, IntDistribution):
        return trial.suggest_int(param.key, d.low, d.high, log=d.log, step=d.step)
    if isinstance(d, CategoricalDistribution):
        return trial.suggest_categorical(param.key, d.choices)
    raise TypeError(f"{param.key}: unsupported distribution {d!r}")


@dataclass(frozen=True)
class TrialPlan:
    """What every trial of this worker shares: the spec (with ``sweep.*`` settings applied), the command
    line's config overrides, the searched params, seeds, where runs go."""

    spec: SweepSpec
    params: tuple[Param, ...]
    cli: tuple[str, ...]
    seeds: tuple[int, ...]
    out_dir: Path
    study_name: str
    parent_run_id: str | None = None
    client: SweepClient | None = None  # None: tracking disabled
    tags: dict[str, str] = field(default_factory=dict)

    def budget(self) -> list[str]:
        values = {key: getattr(self.spec, name) for name, key in BUDGET_KEYS.items()}
        return ["train.final_eval=true", *(f"{key}={v}" for key, v in values.items() if v is not None)]

    def overrides(self, values: dict[str, Any], seed: int | None = None) -> list[str]:
        """The override line of one training run: base, command line, sampled params, budget, seed."""
        sampled = [p.override(values[p.key]) for p in self.params if p.key in values]
        out = [*self.spec.base, *self.cli, *sampled, *self.budget()]
        if seed is not None:
            out.append(f"seed={seed}")
        return out


class Pruned(StopRun):
    """The pruner rejected the trial at a periodic evaluation."""


class Reporter:
    """The runner's ``on_eval`` hook: report the metric to the trial, stop the run when it should be pruned."""

    def __init__(self, trial: optuna.Trial, metric: str, offset: int = 0) -> None:
        self.trial, self.metric, self.offset = trial, metric, offset

    def __call__(self, step: int, summary: dict[str, Any]) -> None:
        value = summary.get(self.metric)
        if not isinstance(value, int | float) or not math.isfinite(value):
            return
        self.trial.report(float(value), self.offset + step)
        if self.trial.should_prune():
            raise Pruned(f"pruned at step {self.offset + step} ({self.metric}={value:.4g})")


class Objective:
    """``study.optimize``'s function; see the module docstring."""

    def __init__(self, plan: TrialPlan, worker: str) -> None:
        self.plan, self.worker = plan, worker

    def __call__(self, trial: optuna.Trial) -> float:
        raise_pending()  # a Ctrl-C that landed in a finalizer between trials stops here, not after one more
        trial.set_user_attr(WORKER_ATTR, self.worker)
        values = {p.key: suggest(trial, p) for p in self.plan.params}
        try:
            return self._run(trial, values)
        except optuna.TrialPruned:
            raise
        except KeyboardInterrupt as exc:
            trial.set_user_attr(INTERRUPTED_ATTR, type(exc).__name__)
            self._settle(trial.number)
            raise
        except Exception as exc:
            trial.set_user_attr(ERROR_ATTR, f"{type(exc).__name__}: {exc}"[:1000])
            self._settle(trial.number)
            raise

    def _settle(self, number: int) -> None:
        """The trial's MLflow runs say FAIL too (completed and pruned ones are tagged as they end)."""
        if self.plan.client is None:
            return
        try:
            self.plan.client.settle_trial_runs(self.plan.study_name, number, "FAIL")
        except Exception as exc:  # the trial's own error is what matters: say this one, do not raise it instead
            print(f"note: could not tag trial {number}'s MLflow runs optuna_state=FAIL ({exc})", file=sys.stderr)

    def _run(self, trial: optuna.Trial, values: dict[str, Any]) -> float:
        from diana_lab.training import train

        plan = self.plan
        seeds: tuple[int | None, ...] = plan.seeds or (None,)
        # the trial's own command line, for its reproduce line: a rerun of the study may change the budget
        trial.set_user_attr(OVERRIDES_ATTR, plan.overrides(values))
        trial.set_user_attr(SEEDS_ATTR, list(plan.seeds))
        trial_dir = plan.out_dir / f"trial_{trial.number:04d}"
        tags = {**plan.tags, "optuna_study": plan.study_name, "optuna_trial": trial.number}
        group = _SeedGroup.open(plan, trial.number, values, tags) if len(seeds) > 1 else None
        parent = group.run_id if group is not None else plan.parent_run_id
        scores: list[float] = []
        summaries: list[dict[str, Any]] = []
        run_ids: list[str] = []
        status = "FAILED"
        try:
            for i, seed in enumerate(seeds):
                overrides = plan.overrides(values, seed)
                name = f"{plan.study_name}-t{trial.number:04d}" + (f"-s{seed}" if len(seeds) > 1 else "")
                overrides.append(f"tracking.run_name={format_value(name)}")
                cfg, choices = compose_run(overrides)
                ctx = RunContext(
                    run_dir=trial_dir / f"seed_{seed}" if len(seeds) > 1 else trial_dir,
                    choices=choices,
                    overrides=tuple(overrides),
                    parent_run_id=parent,
                    tags=tags if seed is None else {**tags, "optuna_seed": seed},
                    on_eval=Reporter(trial, plan.spec.metric, offset=i * int(cfg.train.total_timesteps)),
                )
                try:
                    result = train(cfg, ctx)
                except Pruned as exc:
                    partial = getattr(exc, "result", None)
                    if partial is not None and partial.run_id:
                        _tag(plan.client, partial.run_id, {"optuna_state": "PRUNED"})
                    status = "KILLED"
                    raise optuna.TrialPruned(str(exc)) from exc
                except KeyboardInterrupt:
                    status = "KILLED"
                    raise
                if result.run_id:
                    run_ids.append(result.run_id)
                    trial.set_user_attr("run_ids", run_ids)
                value = result.eval_summary.get(plan.spec.metric)
                if not isinstance(value, int | float) or not math.isfinite(value):
                    raise ValueError(f"the final evaluation gave {plan.spec.metric}={value!r} (not a finite number)")
                scores.append(float(value))
                summaries.append(result.eval_summary)
                _tag(plan.client, result.run_id, {"optuna_state": "COMPLETE", "optuna_value": value})
            objective = statistics.fmean(scores)
            summary = _mean_summary(summaries)
            for key, v in summary.items():
                trial.set_user_attr(key, v)
            trial.set_user_attr("run_dir", str(trial_dir))
            if group is not None:
                group.finish(objective, summary, scores)
            status = "FINISHED"
            return objective
        finally:
            if group is not None:
                group.end(status)


def _tag(client: SweepClient | None, run_id: str | None, tags: dict[str, Any]) -> None:
    if client is not None and run_id:
        client.set_tags(run_id, tags)


def _mean_summary(summaries: list[dict[str, Any]]) -> dict[str, float]:
    out: dict[str, float] = {}
    for key in SUMMARY_ATTRS:
        vals = [float(s[key]) for s in summaries if isinstance(s.get(key), int | float) and math.isfinite(s[key])]
        if vals:
            out[key] = statistics.fmean(vals)
    return out


class _SeedGroup:
    """With several seeds a trial gets its own MLflow run (the mean objective), the seeds' runs nested in it."""

    def __init__(self, client: SweepClient, run_id: str) -> None:
        self.client, self.run_id = client, run_id

    @classmethod
    def open(cls, plan: TrialPlan, number: int, values: dict[str, Any], tags: dict[str, Any]) -> _SeedGroup | None:
        if plan.client is None:
            return None
        name = f"{plan.study_name}-t{number:04d}"
        run_id = plan.client.create_run(name, {**tags, "optuna_seeds": list(plan.seeds)}, plan.parent_run_id)
        plan.client.log_new_params(run_id, values)
        return cls(plan.client, run_id)

    def finish(self, objective: float, summary: dict[str, float], scores: list[float]) -> None:
        metrics = {"objective": objective, **{f"mean_{k}": v for k, v in summary.items()}}
        if len(scores) > 1:
            metrics["objective_std"] = statistics.stdev(scores)
        self.client.log_metrics(self.run_id, metrics, 0)
        self.client.set_tags(self.run_id, {"optuna_state": "COMPLETE", "optuna_value": objective})

    def end(self, status: str) -> None:
        self.client.set_status(self.run_id, status)
