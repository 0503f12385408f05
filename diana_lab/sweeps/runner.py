"""Run (or continue) a study: check everything, open the study and its MLflow run, optimise, report.

:func:`run_sweep` is the whole of ``python -m diana_lab.sweep``. Its order matters for users:

1. the sweep file, the command line and a trial config with every searched key at its low end are checked
   before anything is created, so a typo fails in seconds, naming the file and line, with exit status 2;
2. the study is created or loaded (several workers, reruns), trials left RUNNING by killed workers of this
   machine (with an RDB storage, of any machine whose heartbeats stopped) are failed and their MLflow runs
   ended KILLED, and the study's MLflow run is created or reopened;
3. trials run until the study holds ``n_trials`` counted trials (:mod:`diana_lab.sweeps.study`), the timeout
   passes, or Ctrl-C / SIGTERM (the trial FAIL, its run and the study's run KILLED; rerun to continue);
4. whatever happened, the study's run gets the trials CSV, the plots and the best trial, and the console the
   table of the best trials and the command that reproduces the best one.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import optuna
from omegaconf import DictConfig, OmegaConf
from optuna.distributions import FloatDistribution

from diana_lab import config as C
from diana_lab.config.run import TrackingConfig
from diana_lab.config.sweep import SweepConfig
from diana_lab.core.validation import ConfigError, check_seed
from diana_lab.errors import UserError
from diana_lab.sweeps import report
from diana_lab.sweeps.baseline import enqueue_baseline
from diana_lab.sweeps.compose import compose_run, override_keys
from diana_lab.sweeps.confirm import enqueue_top
from diana_lab.sweeps.mlflow_runs import PARENT_ATTR, TRACKING_ATTR, ParentRun, SweepClient
from diana_lab.sweeps.objective import Objective, TrialPlan
from diana_lab.sweeps.space import Param
from diana_lab.sweeps.spec import BUDGET_KEYS, SweepSpec, load_spec
from diana_lab.sweeps.storage import dashboard_command, display_url, make_storage, resolve_storage
from diana_lab.sweeps.study import (
    TrialBudget,
    fail_dead_trials,
    make_pruner,
    make_sampler,
    open_study,
    wait_for,
    worker_id,
)
from diana_lab.sweeps.workers import LocalWorkers
from diana_lab.tracking.git import git_commit
from diana_lab.training.runner import RUN_GROUPS
from diana_lab.training.signals import interrupts_as_exceptions

__all__ = ["SweepResult", "run_sweep", "sweep_overrides"]


class _QuietInterrupts(logging.Filter):
    """Optuna logs a failed trial with its traceback; for Ctrl-C / SIGTERM that is noise, not a bug report."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and isinstance(record.exc_info[1], KeyboardInterrupt):
            record.exc_info, record.exc_text = None, None
        return True


logging.getLogger("optuna.study._optimize").addFilter(_QuietInterrupts())

PARENT_WAIT_S = 60.0  # how long a worker waits for the study's creator to create the MLflow parent run
_ABSENT = object()


@dataclass
class SweepResult:
    study_name: str
    storage: str
    status: str  # FINISHED | KILLED | FAILED (this worker's ending)
    counts: dict[str, int] = field(default_factory=dict)
    best_value: float = math.nan
    best_params: dict[str, Any] = field(default_factory=dict)
    best_trial: int | None = None
    metric: str = ""  # the objective's summary key
    reproduce: str | None = None
    parent_run_id: str | None = None
    table: str = ""


def sweep_overrides(overrides: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """The command line's config overrides for every trial: all but the ``sweep.*`` ones."""
    return tuple(o for o in overrides if not o.lstrip("+~").startswith(("sweep.", "sweep=")))


def _corners(params: tuple[Param, ...]) -> list[dict[str, Any]]:
    """The searched values the start-up check composes: every key at its low end, then at its high end; a
    categorical key steps through its choices (so there are as many corners as the longest list of choices)."""
    ends = [p.ends() for p in params]
    return [{p.key: e[min(i, len(e) - 1)] for p, e in zip(params, ends)} for i in range(max(map(len, ends)))]


def _rejected(spec: SweepSpec, params: tuple[Param, ...], values: dict[str, Any], exc: ConfigError) -> ConfigError:
    """The error for a corner the config rejects, naming the file, the line and the searched key it blames."""
    text = str(exc)
    p = next((p for p in params if text.startswith(p.key) or f"override {p.key}=" in text), None)
    if p is None:  # e.g. two searched keys that do not fit together
        return ConfigError(f"{spec.where()}: with {' '.join(q.override(values[q.key]) for q in params)}: {exc}")
    hint = ""
    if isinstance(p.distribution, FloatDistribution) and "to Integer" in text:
        hint = " (an integer key: search it with int(interval(a, b)) or range(a, b))"
    return ConfigError(
        f"{spec.where(p.key)}: params.{p.key}: {p.expression} reaches {values[p.key]!r}, which the config rejects: "
        f"{exc}{hint}"
    )


def _check(spec: SweepSpec, params: tuple[Param, ...], cli: tuple[str, ...]) -> TrackingConfig:
    """Fail fast on a bad base override, an unknown searched key, a bad seed, or an end of a searched range (or a
    choice) the schema rejects: otherwise each trial would fail inside training and the sweep exit 0."""
    plan = TrialPlan(spec=spec, params=params, cli=cli, seeds=(), out_dir=Path("."), study_name="check")
    try:
        cfg, _ = compose_run(plan.overrides({}))
        check_seed("seed", cfg.get("seed"))
    except ConfigError as exc:
        raise ConfigError(f"{spec.where()}: base overrides and command line: {exc}") from exc
    for p in params:
        if OmegaConf.select(cfg, p.key, default=_ABSENT, throw_on_missing=False) is _ABSENT:
            raise ConfigError(f"{spec.where(p.key)}: params.{p.key}: no such key in the composed config")
    for values in _corners(params):
        try:
            cfg, _ = compose_run(plan.overrides(values))
            typed = C.validate(cfg, [g for g in RUN_GROUPS if g in cfg])
        except ConfigError as exc:
            raise _rejected(spec, params, values, exc) from exc
    return typed["tracking"]


def _command_line_budget(spec: SweepSpec, settings: SweepConfig, fixed: set[str]) -> SweepSpec:
    """The command line's ``train.total_timesteps``, ``eval.episodes`` and ``eval.every`` win over the sweep file's
    budget, as every other override given there does (the budget is applied after it, so it would silently
    replace them). Given together with the ``sweep.*`` key that sets the same budget they disagree: an error."""
    dropped: dict[str, None] = {}
    for field_name, key in BUDGET_KEYS.items():
        if key not in fixed:
            continue
        if getattr(settings, field_name) is not None:
            raise ConfigError(f"{key} and sweep.{field_name} both set the trials' budget; give one of them")
        if getattr(spec, field_name) is not None:
            print(f"note: {key} is set on the command line, so budget.{field_name} is not used", file=sys.stderr)
        dropped[field_name] = None
    if settings.seeds and "seed" in fixed:
        raise ConfigError("seed and sweep.seeds both set the trials' training seeds; give one of them")
    return dataclasses.replace(spec, **dropped)


SETUP_ATTR = "trial_setup"  # the override line every trial shares (all but the sampled params), and the seeds


def _note_setup_change(study: optuna.Study, plan: TrialPlan) -> None:
    """Say so when this worker's trials would run otherwise than the study's earlier ones (another budget,
    base or command line): their values are then not comparable, though the pruner and the best trial compare
    them. Allowed (a study may be topped up on purpose), but never silent."""
    setup = {"overrides": plan.overrides({}), "seeds": list(plan.seeds)}
    before = study.user_attrs.get(SETUP_ATTR)
    if before is None:
        study.set_user_attr(SETUP_ATTR, setup)
        return
    if before == setup:
        return
    old, new = before.get("overrides", []), setup["overrides"]
    gone, added = [o for o in old if o not in new], [o for o in new if o not in old]
    if before.get("seeds") != setup["seeds"]:
        gone.append(f"seeds {before.get('seeds')}")
        added.append(f"seeds {setup['seeds']}")
    print(
        f"note: study '{study.study_name}' ran its earlier trials with {' '.join(gone) or '(nothing else)'}; these "
        f"run with {' '.join(added) or '(nothing else)'}. Their values are not comparable, though the pruner and "
        "the best trial compare them: give another sweep.name for a separate study. Each trial's reproduce line "
        "is its own.",
        file=sys.stderr,
    )
    study.set_user_attr(SETUP_ATTR, setup)


def _parent_run(
    study: optuna.Study, created: bool, tracking: TrackingConfig, name: str, tags: dict[str, Any]
) -> ParentRun | None:
    if not tracking.enabled:
        return None
    run_id = study.user_attrs.get(PARENT_ATTR)
    if run_id is None and not created and not study.get_trials(deepcopy=False):
        # the worker that created the study is creating the MLflow run (and, maybe, the MLflow database)
        wait_for(lambda: PARENT_ATTR in study.user_attrs, PARENT_WAIT_S)
        run_id = study.user_attrs.get(PARENT_ATTR)
    client = SweepClient(tracking.uri, tracking.experiment)
    kept = study.user_attrs.get(TRACKING_ATTR)
    if run_id is not None and kept is not None and kept != client.uri:
        # on another store the parent run cannot be found: a second parent would be made and the study's
        # record of the first overwritten
        raise UserError(
            f"tracking.uri: this worker's MLflow store is '{client.uri}', but study '{study.study_name}' keeps its "
            f"runs (parent run {run_id}) in '{kept}'. Give every worker of a study that tracking.uri (an MLflow "
            "server or a database every machine reaches), or another sweep.name for a new study."
        )
    parent = ParentRun.open(client, run_id, name, tags)
    if parent.created:
        study.set_user_attr(PARENT_ATTR, parent.run_id)
        study.set_user_attr(TRACKING_ATTR, client.uri)
    return parent


def _report(
    study: optuna.Study, plan: TrialPlan, parent: ParentRun | None, out_dir: Path, full: bool, top: int
) -> SweepResult:
    counts = report.counts(study)
    result = SweepResult(
        study.study_name,
        "",
        "",
        counts=counts,
        metric=plan.spec.metric,
        parent_run_id=parent.run_id if parent else None,
    )
    best = report.best_trial(study)
    if best is not None:
        result.best_value, result.best_params, result.best_trial = float(best.value), dict(best.params), best.number
        result.reproduce = report.reproduce_command(plan, best)
    result.table = report.top_table(study, plan.spec.metric, top).to_string(index=False)
    csv = report.write_trials_csv(study, out_dir / "study" / "trials.csv")
    if parent is None:
        return result
    client = parent.client
    finished = counts["complete"] + counts["pruned"] + counts["fail"]
    client.log_metrics(parent.run_id, {f"trials_{k}": v for k, v in counts.items() if k != "waiting"}, finished)
    client.log_artifact(parent.run_id, csv, "study")
    if best is not None:
        ids = best.user_attrs.get("run_ids") or []
        summary = {k: v for k, v in best.user_attrs.items() if isinstance(v, int | float) and k != "number"}
        info = {"number": best.number, "value": best.value, "overrides": result.reproduce, "summary": summary}
        info["run_id"] = ids[0] if ids else None
        parent.log_best(info, best.params, finished)
    if full:
        for path in report.write_plots(study, out_dir / "study" / "plots"):
            client.log_artifact(parent.run_id, path, "plots")
    return result


def _source_study(storage: optuna.storages.BaseStorage, name: str) -> optuna.Study:
    try:
        return optuna.load_study(study_name=name, storage=storage)
    except KeyError:
        names = [s.study_name for s in optuna.get_all_study_summaries(storage)]
        raise ConfigError(f"sweep.top_of={name}: no such study in sweep.storage (it holds {names or 'none'})") from None


def _hydra_overrides() -> list[str]:
    """The command line's ``hydra.*`` overrides (logging, launcher), for the workers this one starts."""
    try:
        from hydra.core.hydra_config import HydraConfig

        return [str(o) for o in OmegaConf.to_container(HydraConfig.get().overrides.hydra, resolve=False)]
    except ValueError:  # called outside a Hydra app (tests, notebooks)
        return []


def run_sweep(cfg: DictConfig, out_dir: Path, overrides: tuple[str, ...] = ()) -> SweepResult:
    """Run this worker's share of the study described by ``cfg.sweep`` (see the module docstring)."""
    settings: SweepConfig = C.to_object("sweep", cfg.sweep)
    spec = load_spec(settings.name).with_settings(settings)
    cli = sweep_overrides(overrides)
    fixed = override_keys(cli)
    spec = _command_line_budget(spec, settings, fixed)
    params = tuple(p for p in spec.params if p.key not in fixed)
    if not params:
        raise ConfigError(f"{spec.where()}: every searched key is fixed on the command line; nothing to search")
    for p in spec.params:
        if p.key in fixed:
            print(f"note: {p.key} is set on the command line, so it is not searched", file=sys.stderr)
    tracking = _check(spec, params, cli)

    parent: ParentRun | None = None
    stale: list[int] = []  # trials of dead workers (any machine) failed by an RDB storage's heartbeats

    def on_stale(study: optuna.Study, trial: optuna.trial.FrozenTrial) -> None:
        run = parent
        if run is None:  # at start-up: their runs are ended with the other dead trials' below
            stale.append(trial.number)
            return
        try:
            run.client.kill_running(name, [trial.number])
        except Exception as exc:  # the next trial matters more than this run's status
            print(f"note: could not end trial {trial.number}'s MLflow run ({exc})", file=sys.stderr)
        print(f"note: trial {trial.number}'s worker stopped sending heartbeats: marked FAIL", file=sys.stderr)

    storage_url = resolve_storage(settings.storage)
    storage = make_storage(storage_url, settings.heartbeat_s, on_stale)
    name = settings.study_name or spec.name
    if name == settings.top_of:
        raise ConfigError(f"sweep.top_of={name}: the re-runs need a study of their own: give another sweep.study_name")
    source = _source_study(storage, settings.top_of) if settings.top_of else None
    pruner = "none" if source is not None else settings.pruner  # a re-run is a full measurement
    sampler = make_sampler(settings.sampler, settings.sampler_seed)
    study, created = open_study(
        storage, name, spec.direction, sampler, make_pruner(pruner, settings.pruner_startup_trials, spec.prune_after)
    )
    if source is not None:
        top = enqueue_top(study, source, settings.top_k, {p.key for p in params})
        spec = dataclasses.replace(spec, n_trials=len(top))
        print(
            f"re-running {len(top)} trial(s) of study '{source.study_name}' ({[t.number for t in top]}: the top "
            f"{settings.top_k}, and its baseline when it is not among them) on "
            f"seeds {list(settings.seeds)}",
            file=sys.stderr,
        )
    dead = fail_dead_trials(study)
    with warnings.catch_warnings():  # RDB storages: dead workers of other machines too (else a last slot they
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)  # hold would stop every worker)
        optuna.storages.fail_stale_trials(study)
    dead += stale
    if dead:
        print(f"note: trial(s) {dead} were left RUNNING by a killed worker: marked FAIL", file=sys.stderr)
    done = len(study.get_trials(deepcopy=False))
    if settings.sampler_seed is not None and done:
        # a rerun continues the seeded sequence instead of restarting it (which proposed the first trials' points
        # again): still a function of the seed and of the study, so the same rerun gives the same points
        study.sampler = make_sampler(settings.sampler, (settings.sampler_seed + done) % 2**32)

    commit = git_commit()
    tags = {
        "sweep": spec.name,
        "sweep_file": str(spec.path.resolve()),
        "optuna_study": name,
        "optuna_storage": display_url(storage_url),
        "sampler": settings.sampler,
        "pruner": pruner,
        **({"top_of": settings.top_of} if settings.top_of else {}),
        "objective": f"{spec.direction} {spec.metric}",
        "n_trials": spec.n_trials,
        "base_overrides": " ".join(spec.base),
        "overrides": " ".join(cli),
        "git_commit": commit,
        "mlflow.source.git.commit": commit,
    }
    result = SweepResult(name, storage_url, "FAILED")
    plan: TrialPlan | None = None
    helpers: LocalWorkers | None = None
    status = "FAILED"
    with interrupts_as_exceptions():
        try:
            parent = _parent_run(study, created, tracking, f"sweep-{name}", tags)
            if parent is not None:
                parent.client.log_new_params(parent.run_id, {f"space.{p.key}": p.expression for p in spec.params})
                parent.client.kill_running(name, dead)  # the dead trials' runs, left RUNNING by their worker
            plan = TrialPlan(
                spec=spec,
                params=params,
                cli=cli,
                seeds=tuple(settings.seeds),
                out_dir=out_dir,
                study_name=name,
                parent_run_id=parent.run_id if parent else None,
                client=parent.client if parent else None,
                tags={"sweep": spec.name},
            )
            _note_setup_change(study, plan)
            if created and source is None and settings.baseline:
                enqueue_baseline(study, compose_run(plan.overrides({}))[0], params)
            budget = TrialBudget(spec.n_trials)
            left = budget.remaining(study)
            print(
                f"study '{name}' ({display_url(storage_url)}): {spec.n_trials - left} of {spec.n_trials} trials "
                f"done or running; {spec.direction} {spec.metric}",
                file=sys.stderr,
            )
            if left > 0 and settings.workers > 1:
                helpers = LocalWorkers.start(
                    min(settings.workers, left),
                    overrides,
                    storage_url,
                    out_dir,
                    settings.sampler_seed,
                    _hydra_overrides(),
                )
            if left > 0:
                study.optimize(
                    Objective(plan, worker_id()),
                    n_trials=spec.n_trials,  # a cap for this worker; the budget callback stops it earlier
                    timeout=settings.timeout_s,
                    catch=(Exception,),
                    callbacks=[budget],
                    gc_after_trial=True,
                )
            if helpers is not None:
                print("waiting for the other workers' trials", file=sys.stderr)
                helpers.wait()
            status = "FINISHED"
        except KeyboardInterrupt:
            status = "KILLED"
            raise
        finally:
            if helpers is not None and status != "FINISHED":
                helpers.stop()
            if plan is not None:
                try:
                    result = _report(study, plan, parent, out_dir, status == "FINISHED", settings.top)
                except KeyboardInterrupt:
                    status = "KILLED"
                finally:
                    result.storage, result.status = storage_url, status
            if parent is not None:
                others_running = any(
                    t.state == optuna.trial.TrialState.RUNNING for t in study.get_trials(deepcopy=False)
                )
                if status != "FINISHED" or not others_running:
                    parent.end(status)
    return result


def summary_text(result: SweepResult, top: int = 10) -> str:
    """The console report: counts, the top trials, the best trial's command, where to look next."""
    c = result.counts
    lines = [
        f"study '{result.study_name}': {c.get('complete', 0)} complete, {c.get('pruned', 0)} pruned, "
        f"{c.get('fail', 0)} failed, {c.get('running', 0)} running",
    ]
    if result.table:
        lines += ["", f"top trials (at most {top}):", result.table]
    if result.best_trial is not None:
        lines += [
            "",
            f"best trial {result.best_trial}: {result.metric or 'value'} = {result.best_value:.4g}",
            "reproduce:",
            f"  {result.reproduce}",
        ]
    lines += ["", f"dashboard: {dashboard_command(result.storage)}"]
    if result.parent_run_id:
        lines.append(f"MLflow study run: {result.parent_run_id}")
    return "\n".join(lines)
