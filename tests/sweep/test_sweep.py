"""``python -m diana_lab.sweep`` end to end with tiny budgets: trials, nested MLflow runs, resume, failures,
pruning through the runner's periodic evaluation."""

from __future__ import annotations

import optuna
from optuna.pruners import BasePruner

from diana_lab.sweeps.mlflow_runs import ParentRun, SweepClient
from diana_lab.sweeps.objective import Objective, TrialPlan
from diana_lab.sweeps.spec import load_spec

from .helpers import load_study, mlflow_runs, run_in_process, states, sweep_args, write_sweep


def _metric(metrics: dict, key: str) -> float:
    """An evaluation metric under either naming (``eval_<key>`` or the older ``eval/<key>``)."""
    return metrics[f"eval_{key}"] if f"eval_{key}" in metrics else metrics[f"eval/{key}"]


def test_three_trial_sweep_records_trials_and_nested_runs(tmp_path, capsys):
    path = write_sweep(tmp_path, n_trials=3)
    assert run_in_process(sweep_args(tmp_path, path)) == 0
    out = capsys.readouterr().out
    study = load_study(tmp_path)
    assert states(study) == ["COMPLETE"] * 3
    client, parents, children = mlflow_runs(tmp_path)
    assert len(parents) == 1 and len(children) == 3
    parent = parents[0]
    assert parent.info.status == "FINISHED"
    assert parent.data.tags["sweep"] == "tiny" and parent.data.tags["optuna_study"] == "tiny"
    assert parent.data.tags["optuna_storage"].endswith("optuna.journal")
    assert study.user_attrs["mlflow_parent_run_id"] == parent.info.run_id
    by_trial = {int(r.data.tags["optuna_trial"]): r for r in children}
    assert sorted(by_trial) == [0, 1, 2]
    for number, run in by_trial.items():
        trial = study.trials[number]
        assert run.data.tags["mlflow.parentRunId"] == parent.info.run_id
        assert run.info.status == "FINISHED" and run.data.tags["optuna_state"] == "COMPLETE"
        assert float(run.data.params["algo.learning_rate"]) == trial.params["algo.learning_rate"]
        assert _metric(run.data.metrics, "spl") == trial.value  # the objective is the final evaluation's SPL
        assert "rollout/ep_rew_mean" in run.data.metrics  # training metrics
        assert "model/model.zip" in {a.path for a in client.list_artifacts(run.info.run_id, "model")}
        assert trial.user_attrs["run_ids"] == [run.info.run_id]
    best = study.best_trial
    assert parent.data.tags["best_trial"] == str(best.number)
    assert float(parent.data.tags["best.reward.terms.goal.weight"]) == best.params["reward.terms.goal.weight"]
    assert parent.data.metrics["best_value"] == best.value
    study_files = {a.path for a in client.list_artifacts(parent.info.run_id, "study")}
    assert {"study/trials.csv", "study/best_params.json"} <= study_files
    plots = {a.path for a in client.list_artifacts(parent.info.run_id, "plots")}
    assert "plots/optimization_history.html" in plots and "plots/parallel_coordinate.html" in plots
    assert "reproduce:" in out and f"reward.terms.goal.weight={best.params['reward.terms.goal.weight']!r}" in out
    assert "python -m diana_lab world=flat" in out and "optuna-dashboard" in out


def test_rerun_continues_the_study_and_its_mlflow_run(tmp_path):
    path = write_sweep(tmp_path, n_trials=1)
    assert run_in_process(sweep_args(tmp_path, path)) == 0
    _, (parent,), _ = mlflow_runs(tmp_path)
    # the same command with a larger budget tops the study up to it, under the same MLflow run
    assert run_in_process(sweep_args(tmp_path, path, "sweep.n_trials=2", out="again")) == 0
    assert states(load_study(tmp_path)) == ["COMPLETE"] * 2
    _, parents, children = mlflow_runs(tmp_path)
    assert [p.info.run_id for p in parents] == [parent.info.run_id] and len(children) == 2
    assert parents[0].info.status == "FINISHED"
    # once the budget is spent, rerunning runs nothing more
    assert run_in_process(sweep_args(tmp_path, path, "sweep.n_trials=2", out="done")) == 0
    assert len(load_study(tmp_path).trials) == 2


def test_failing_trial_is_recorded_and_the_study_goes_on(tmp_path):
    marker = tmp_path / "failed_once"
    boom = ["reward.terms.step.fn=tests.sweep.helpers.fail_once", f"+reward.terms.step.params.marker='{marker}'"]
    path = write_sweep(tmp_path, n_trials=2, extra_base=boom)
    assert run_in_process(sweep_args(tmp_path, path)) == 0
    study = load_study(tmp_path)
    assert states(study) == ["FAIL", "COMPLETE"]  # a failure counts towards n_trials
    assert "deliberate failure inside training" in study.trials[0].user_attrs["error"]
    _, parents, children = mlflow_runs(tmp_path)
    by_trial = {int(r.data.tags["optuna_trial"]): r.info.status for r in children}
    assert by_trial == {0: "FAILED", 1: "FINISHED"}
    states_tagged = {int(r.data.tags["optuna_trial"]): r.data.tags.get("optuna_state") for r in children}
    assert states_tagged == {0: "FAIL", 1: "COMPLETE"}  # the failed trial's run said nothing before
    assert parents[0].info.status == "FINISHED"


def test_a_rerun_with_another_budget_is_noted_and_each_trial_reproduces_as_it_ran(tmp_path, capsys):
    """The reproduce line used to be built from the latest command line: after a rerun with another budget it
    named that budget, not the one the best trial had trained with."""
    path = write_sweep(tmp_path, n_trials=1, timesteps=128)
    assert run_in_process(sweep_args(tmp_path, path, "tracking.enabled=false")) == 0
    capsys.readouterr()
    rerun = ("sweep.n_trials=2", "sweep.timesteps=64", "tracking.enabled=false")
    assert run_in_process(sweep_args(tmp_path, path, *rerun, out="again")) == 0
    out, err = capsys.readouterr()
    assert "ran its earlier trials with train.total_timesteps=128" in err and "train.total_timesteps=64" in err
    study = load_study(tmp_path)
    ran = {t.number: t.user_attrs["overrides"] for t in study.trials}
    assert "train.total_timesteps=128" in ran[0] and "train.total_timesteps=64" in ran[1]
    best = study.best_trial
    line = out.split("reproduce:\n", 1)[1].splitlines()[0]
    assert f"train.total_timesteps={128 if best.number == 0 else 64}" in line
    # whichever is best: the first trial's line names its own budget under the rerun's plan
    import dataclasses

    from diana_lab.sweeps.report import reproduce_command

    spec = dataclasses.replace(load_spec(str(path)), timesteps=64)  # the rerun's budget
    plan = TrialPlan(spec=spec, params=spec.params, cli=(), seeds=(), out_dir=tmp_path, study_name="tiny")
    assert "train.total_timesteps=64" in " ".join(plan.overrides({}))
    assert "train.total_timesteps=128" in reproduce_command(plan, study.trials[0])


class PruneAll(BasePruner):
    def prune(self, study, trial) -> bool:
        return True


def test_pruning_stops_training_at_a_periodic_evaluation(tmp_path):
    spec = load_spec(str(write_sweep(tmp_path, timesteps=512, eval_every=128)))
    client = SweepClient(f"sqlite:///{tmp_path}/mlflow.db", "diana_lab")
    parent = ParentRun.open(client, None, "sweep-test", {"sweep": "tiny"})
    plan = TrialPlan(
        spec=spec,
        params=spec.params,
        cli=(f"tracking.uri=sqlite:///{tmp_path}/mlflow.db",),
        seeds=(),
        out_dir=tmp_path / "out",
        study_name="pruning",
        parent_run_id=parent.run_id,
        client=client,
    )
    study = optuna.create_study(direction="maximize", pruner=PruneAll())
    study.optimize(Objective(plan, "test:1:1"), n_trials=1)
    (trial,) = study.trials
    assert trial.state == optuna.trial.TrialState.PRUNED
    assert list(trial.intermediate_values) and max(trial.intermediate_values) < 512  # stopped early
    _, _, children = mlflow_runs(tmp_path)
    (run,) = children
    assert run.info.status == "KILLED" and run.data.tags["optuna_state"] == "PRUNED"
    assert run.data.tags["mlflow.parentRunId"] == parent.run_id


def test_the_reproduce_line_runs_as_printed_with_an_interpolated_base_override(tmp_path, capsys):
    """The reward-shaping sweep ties pitch's deadband to roll's with a relative interpolation; pasted into
    ``python -m diana_lab`` it used to fail (``Interpolation key 'roll.params.deadband_deg' not found``) while
    the run read its command line's overrides."""
    import shlex

    import pytest
    from omegaconf import OmegaConf

    from tests.training.helpers import run_in_process as train_in_process

    tie = "reward.terms.pitch.params.deadband_deg=${...roll.params.deadband_deg}"
    params = {"reward.terms.roll.params.deadband_deg": "interval(1.0, 9.0)"}
    path = write_sweep(tmp_path, n_trials=1, timesteps=64, extra_base=[tie], params=params)
    assert run_in_process(sweep_args(tmp_path, path, "tracking.enabled=false")) == 0
    out = capsys.readouterr().out
    assert "best trial 0: spl = " in out  # the value is named by its metric
    line = out.split("reproduce:\n", 1)[1].splitlines()[0].strip()
    args = shlex.split(line)
    assert args[:3] == ["python", "-m", "diana_lab"] and tie in args
    run_dir = tmp_path / "again"
    assert train_in_process([*args[3:], "tracking.enabled=false", f"hydra.run.dir={run_dir}"]) == 0
    best = load_study(tmp_path).best_trial.params["reward.terms.roll.params.deadband_deg"]
    cfg = OmegaConf.load(run_dir / ".hydra" / "config.yaml")
    assert OmegaConf.select(cfg, "reward.terms.pitch.params.deadband_deg") == pytest.approx(best)
    assert OmegaConf.select(cfg, "reward.terms.roll.params.deadband_deg") == pytest.approx(best)


def test_with_several_seeds_the_reproduce_line_is_a_multirun_over_them(tmp_path):
    """The trial's value was the mean over its seeds, so one seed would not reproduce it."""
    import optuna

    from diana_lab.sweeps.report import reproduce_command

    path = write_sweep(tmp_path)
    spec = load_spec(str(path))
    trial = optuna.trial.create_trial(
        params={"algo.learning_rate": 1e-3, "reward.terms.goal.weight": 5.0},
        distributions={
            "algo.learning_rate": optuna.distributions.FloatDistribution(1e-4, 1e-2, log=True),
            "reward.terms.goal.weight": optuna.distributions.FloatDistribution(1.0, 20.0),
        },
        value=0.5,
    )

    def plan(seeds: tuple[int, ...]) -> TrialPlan:
        return TrialPlan(
            spec=spec, params=spec.params, cli=("world=flat",), seeds=seeds, out_dir=tmp_path, study_name="t"
        )

    several = reproduce_command(plan((3, 4)), trial).split()
    assert several[:4] == ["python", "-m", "diana_lab", "-m"] and several[-1] == "seed=3,4"
    assert "reward.terms.goal.weight=5.0" in several and not any(a.startswith("seed=3 ") for a in several)
    one = reproduce_command(plan((3,)), trial).split()
    assert "-m" not in one[3:] and one[-1] == "seed=3"
    assert not any(a.startswith("seed=") for a in reproduce_command(plan(()), trial).split())


def test_a_seeded_sampler_goes_on_after_a_rerun_and_repeats_it_exactly(tmp_path):
    """A rerun restarted the seeded sequence: its first trial proposed the first trial's points again."""

    def study_of(directory):
        directory.mkdir()
        path = write_sweep(directory, n_trials=1, timesteps=64)
        seeded = ("sweep.sampler=random", "sweep.sampler_seed=3", "tracking.enabled=false")
        assert run_in_process(sweep_args(directory, path, *seeded)) == 0
        assert run_in_process(sweep_args(directory, path, *seeded, "sweep.n_trials=2", out="again")) == 0
        return [t.params for t in load_study(directory).trials]

    first = study_of(tmp_path / "a")
    assert len(first) == 2 and first[1] != first[0]
    assert study_of(tmp_path / "b") == first  # same seed, same reruns: same points


def test_a_worker_on_another_tracking_store_is_refused_naming_both(tmp_path, capsys):
    path = write_sweep(tmp_path, n_trials=1)
    assert run_in_process(sweep_args(tmp_path, path)) == 0
    _, (parent,), _ = mlflow_runs(tmp_path)
    capsys.readouterr()
    other = f"tracking.uri=sqlite:///{tmp_path}/elsewhere.db"
    assert run_in_process(sweep_args(tmp_path, path, "sweep.n_trials=2", other, out="again")) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path}/elsewhere.db" in err and f"{tmp_path}/mlflow.db" in err and parent.info.run_id in err
    assert "Traceback" not in err
    study = load_study(tmp_path)
    assert states(study) == ["COMPLETE"]  # no trial ran on the other store
    assert study.user_attrs["mlflow_parent_run_id"] == parent.info.run_id  # the study's record kept
