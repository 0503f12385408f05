"""The study's bookkeeping without training: what counts towards n_trials, dead workers, samplers, pruners."""

from __future__ import annotations

import subprocess
import sys

import optuna
import pytest
from optuna.samplers import CmaEsSampler, RandomSampler, TPESampler
from optuna.trial import TrialState

from diana_lab.config import ConfigError, compose, to_object
from diana_lab.sweep import expand_shorthand
from diana_lab.sweeps.runner import sweep_overrides
from diana_lab.sweeps.storage import display_url, make_storage
from diana_lab.sweeps.study import (
    ERROR_ATTR,
    INTERRUPTED_ATTR,
    WORKER_ATTR,
    TrialBudget,
    fail_dead_trials,
    make_pruner,
    make_sampler,
    open_study,
    worker_id,
)


def _study() -> optuna.Study:
    return optuna.create_study(direction="maximize")


def test_budget_counts_finished_and_running_trials_but_not_interrupted_ones():
    study = _study()
    done = study.ask()
    study.tell(done, 1.0)
    raised = study.ask()
    raised.set_user_attr(ERROR_ATTR, "RuntimeError: boom")
    study.tell(raised, state=TrialState.FAIL)
    interrupted = study.ask()
    interrupted.set_user_attr(INTERRUPTED_ATTR, "KeyboardInterrupt")
    study.tell(interrupted, state=TrialState.FAIL)
    pruned = study.ask()
    study.tell(pruned, state=TrialState.PRUNED)
    study.ask()  # running in another worker
    budget = TrialBudget(5)
    assert budget.remaining(study) == 1  # complete, raised, pruned, running; not the interrupted one
    study.optimize(lambda t: 0.0, n_trials=10, callbacks=[budget])
    assert len(study.trials) == 6 and budget.remaining(study) == 0  # one more trial, then this worker stops


def test_trials_of_dead_workers_on_this_machine_are_failed_and_do_not_count():
    study = _study()
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    host = worker_id().split(":")[0]
    dead = study.ask()
    dead.set_user_attr(WORKER_ATTR, f"{host}:{int(gone.stdout)}:1")
    alive = study.ask()
    alive.set_user_attr(WORKER_ATTR, worker_id())
    elsewhere = study.ask()
    elsewhere.set_user_attr(WORKER_ATTR, "another-machine:1:1")
    assert fail_dead_trials(study) == [dead.number]
    assert [t.state for t in study.trials] == [TrialState.FAIL, TrialState.RUNNING, TrialState.RUNNING]
    assert TrialBudget(3).remaining(study) == 1


def test_open_study_creates_once_then_loads(tmp_path):
    storage = make_storage(str(tmp_path / "s.journal"))
    first, created = open_study(storage, "s", "maximize", RandomSampler(), make_pruner("none"))
    again, created_again = open_study(storage, "s", "maximize", RandomSampler(), make_pruner("none"))
    assert created and not created_again and first._study_id == again._study_id
    with pytest.raises(ValueError, match="created to maximize"):
        open_study(storage, "s", "minimize", RandomSampler(), make_pruner("none"))


@pytest.mark.parametrize(("name", "cls"), [("tpe", TPESampler), ("random", RandomSampler), ("cmaes", CmaEsSampler)])
def test_samplers_run_a_mixed_space(name, cls):
    sampler = make_sampler(name, seed=0)
    assert isinstance(sampler, cls)
    study = optuna.create_study(sampler=sampler)
    study.optimize(lambda t: t.suggest_float("x", 0, 1) + t.suggest_categorical("c", [1, 2]), n_trials=4)
    assert len(study.trials) == 4


def test_sweep_settings_are_checked():
    assert to_object("sweep", compose([], config_name="sweep").sweep).sampler == "tpe"
    for bad, key in [("sweep.sampler=grid", "sweep.sampler"), ("sweep.n_trials=0", "sweep.n_trials")]:
        with pytest.raises(ConfigError, match=key):
            to_object("sweep", compose([bad], config_name="sweep").sweep)


def test_command_line_helpers():
    assert expand_shorthand(["sweep=ppo", "sweep.n_trials=3", "world=flat"]) == [
        "sweep.name=ppo",
        "sweep.n_trials=3",
        "world=flat",
    ]
    assert sweep_overrides(("sweep.name=ppo", "world=flat", "+sweep.x=1", "seed=3")) == ("world=flat", "seed=3")
    assert (
        display_url("postgresql+psycopg2://me:secret@db:5432/optuna") == "postgresql+psycopg2://me:***@db:5432/optuna"
    )


def test_a_storage_that_is_not_a_journal_is_refused_untouched(tmp_path):
    import sqlite3

    db = tmp_path / "mlflow.db"
    sqlite3.connect(db).execute("create table t (x)").connection.commit()
    text = tmp_path / "notes.yaml"
    text.write_text("params: {}\n")
    before = db.read_bytes()
    for storage, message in [
        (db, "an SQLite database, not a journal file (as a storage: sqlite:///PATH)"),
        (text, "not an Optuna journal file; expected a journal file path or an RDB URL"),
        (tmp_path, "a folder; expected a journal file path"),
        ("redis://localhost:6379", "'redis' is not a database SQLAlchemy knows"),
    ]:
        with pytest.raises(ConfigError) as info:
            make_storage(str(storage))
        assert str(info.value).startswith(f"sweep.storage={storage}: ") and message in str(info.value)
    assert db.read_bytes() == before and text.read_text() == "params: {}\n"
    journal = tmp_path / "s.journal"
    open_study(make_storage(str(journal)), "s", "maximize", RandomSampler(), make_pruner("none"))
    assert make_storage(str(journal)) is not None  # an existing journal still opens


def test_the_median_pruner_waits_for_prune_after_steps():
    study = optuna.create_study(direction="maximize", pruner=make_pruner("median", 0, 100))
    for value in (0.5, 0.6):  # two finished trials set the median
        t = study.ask()
        for step in (50, 150):
            t.report(value, step)
        study.tell(t, value)
    t = study.ask()
    t.report(0.0, 50)
    assert not t.should_prune()  # below the median, but before prune_after
    t.report(0.0, 150)
    assert t.should_prune()


def test_prune_after_is_read_from_the_sweep_file_and_the_command_line(tmp_path):
    from diana_lab.config.sweep import SweepConfig
    from diana_lab.sweeps.spec import load_spec

    assert load_spec("reward_shaping").prune_after > 0
    path = tmp_path / "s.yaml"
    path.write_text("budget: {prune_after: 7}\nparams:\n  algo.gamma: interval(0.9, 0.99)\n")
    spec = load_spec(str(path))
    assert spec.prune_after == 7
    assert spec.with_settings(SweepConfig(prune_after=9)).prune_after == 9
    path.write_text("budget: {prune_after: -1}\nparams:\n  algo.gamma: interval(0.9, 0.99)\n")
    with pytest.raises(ConfigError, match=r"budget\.prune_after"):
        load_spec(str(path))
