"""The Optuna study of a sweep: sampler, pruner, opening it from any number of workers, and its trial budget.

Budget. ``sweep.n_trials`` is the study's total, not one worker's: a trial *counts* when it is finished
(COMPLETE, PRUNED, or FAIL because the trial itself raised) or claimed (RUNNING in some worker); an enqueued
trial (WAITING: the baseline, a re-run of :mod:`diana_lab.sweeps.confirm`) counts once a worker takes it.
Each worker checks the count before its first trial and after every trial (:class:`TrialBudget`, Optuna's
``MaxTrialsCallback`` with running trials included, so two workers do not both start the last trial), so
rerunning the same command tops the study up to ``n_trials`` and two workers together run ``n_trials``.
A trial that failed because its worker was interrupted (Ctrl-C, SIGTERM) or died (:func:`fail_dead_trials`)
does not count: a rerun runs its slot again.

Trials record who runs them (``worker``: host, pid, process start time), so a worker can tell a trial left
RUNNING by a killed process on its own machine from one that another live worker is running.
"""

from __future__ import annotations

import os
import socket
import time
import warnings
from collections.abc import Sequence

import optuna
import psutil
from optuna.pruners import BasePruner, MedianPruner, NopPruner, SuccessiveHalvingPruner
from optuna.samplers import BaseSampler, CmaEsSampler, RandomSampler, TPESampler
from optuna.storages import BaseStorage
from optuna.trial import FrozenTrial, TrialState

__all__ = [
    "ERROR_ATTR",
    "INTERRUPTED_ATTR",
    "WORKER_ATTR",
    "TrialBudget",
    "counted",
    "fail_dead_trials",
    "make_pruner",
    "make_sampler",
    "open_study",
    "worker_id",
]

ERROR_ATTR = "error"  # set by the objective when the trial itself raised: such a FAIL counts
INTERRUPTED_ATTR = "interrupted"  # SIGINT / SIGTERM: the FAIL does not count, a rerun repeats the slot
WORKER_ATTR = "worker"  # "host:pid:start" of the process running the trial
OVERRIDES_ATTR = "overrides"  # the trial's override line (base, command line, params, budget), without the seed
SEEDS_ATTR = "seeds"  # its training seeds ([]: the config's seed)
CLAIMED = (TrialState.RUNNING, TrialState.COMPLETE, TrialState.PRUNED)


def make_sampler(name: str, seed: int | None = None) -> BaseSampler:
    """TPE (the default; constant liar on, so parallel workers spread out), random, or CMA-ES (continuous
    parameters; categorical ones fall back to random sampling)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        if name == "tpe":
            return TPESampler(seed=seed, multivariate=True, constant_liar=True)
        if name == "random":
            return RandomSampler(seed=seed)
        if name == "cmaes":
            return CmaEsSampler(seed=seed, warn_independent_sampling=False)
    raise ValueError(f"sweep.sampler: unknown sampler {name!r}")


def make_pruner(name: str, startup_trials: int = 5, warmup_steps: int = 0) -> BasePruner:
    """Pruners judge the periodic evaluations (step = training timesteps); the median pruner only after
    ``startup_trials`` trials have finished and from ``warmup_steps`` training steps on, so early noise (an agent
    that has not learnt yet scores near zero whatever its reward) does not prune at random."""
    if name == "median":
        return MedianPruner(n_startup_trials=startup_trials, n_warmup_steps=warmup_steps)
    if name == "successive_halving":
        return SuccessiveHalvingPruner()
    if name == "none":
        return NopPruner()
    raise ValueError(f"sweep.pruner: unknown pruner {name!r}")


def open_study(
    storage: BaseStorage, name: str, direction: str, sampler: BaseSampler, pruner: BasePruner
) -> tuple[optuna.Study, bool]:
    """Create the study, or load it when it exists (another worker, an earlier run); ``(study, created)``.

    Creating is atomic in every storage, so of two workers starting together exactly one sees ``created``.
    """
    try:
        study = optuna.create_study(
            storage=storage, study_name=name, direction=direction, sampler=sampler, pruner=pruner
        )
        return study, True
    except optuna.exceptions.DuplicatedStudyError:
        study = optuna.load_study(storage=storage, study_name=name, sampler=sampler, pruner=pruner)
    if study.direction.name.lower() != direction:
        raise ValueError(
            f"sweep.direction={direction}: study '{name}' was created to {study.direction.name.lower()}; "
            f"use another sweep.study_name for the other direction"
        )
    return study, False


def counted(trial: FrozenTrial) -> bool:
    """Whether a trial uses up one of ``n_trials`` (see the module docstring)."""
    if trial.state in CLAIMED:
        return True
    return trial.state == TrialState.FAIL and ERROR_ATTR in trial.user_attrs


def used(study: optuna.Study) -> int:
    return sum(counted(t) for t in study.get_trials(deepcopy=False))


class TrialBudget:
    """Stop this worker once the study holds ``n_trials`` counted trials (an ``optimize`` callback)."""

    def __init__(self, n_trials: int) -> None:
        self.n_trials = n_trials

    def remaining(self, study: optuna.Study) -> int:
        return max(self.n_trials - used(study), 0)

    def __call__(self, study: optuna.Study, trial: FrozenTrial) -> None:
        if self.remaining(study) <= 0:
            study.stop()


def worker_id() -> str:
    """``host:pid:start``: the start time tells a live process from a later one that reuses its pid."""
    start = int(psutil.Process().create_time())
    return f"{socket.gethostname()}:{os.getpid()}:{start}"


def _dead(worker: str) -> bool:
    """Whether ``worker`` ran on this machine and that process is gone (other machines: unknown, so no)."""
    try:
        host, pid, start = worker.rsplit(":", 2)
        pid_i, start_i = int(pid), int(start)
    except ValueError:
        return False
    if host != socket.gethostname():
        return False
    try:
        return abs(int(psutil.Process(pid_i).create_time()) - start_i) > 1
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return True


def fail_dead_trials(study: optuna.Study, states: Sequence[TrialState] = (TrialState.RUNNING,)) -> list[int]:
    """Mark FAIL the trials left RUNNING by killed workers of this machine; their numbers.

    RDB storages do this across machines with heartbeats; a journal file has none, so without this a SIGKILLed
    worker's trial would stay RUNNING and keep its slot of the budget. A FAIL written here has no error
    attribute, so it does not count and the slot is run again.
    """
    failed: list[int] = []
    for t in study.get_trials(deepcopy=False, states=tuple(states)):
        worker = t.user_attrs.get(WORKER_ATTR)
        if isinstance(worker, str) and _dead(worker):
            try:
                study.tell(t.number, state=TrialState.FAIL)
                failed.append(t.number)
            except (ValueError, RuntimeError):  # finished meanwhile
                continue
    return failed


def wait_for(predicate: object, timeout_s: float, interval_s: float = 0.5) -> bool:
    """Poll ``predicate()`` until it is true or ``timeout_s`` passes (used to wait for another worker)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return True
        time.sleep(interval_s)
    return bool(predicate())  # type: ignore[operator]
