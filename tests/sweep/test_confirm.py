"""sweep.top_of: the best trials of a study re-run on fresh seeds as a study of their own."""

from __future__ import annotations

import pytest

from .helpers import load_study, run_in_process, states, sweep_args, write_sweep


def test_top_trials_and_the_baseline_are_re_run_on_the_given_seeds_once(tmp_path, capsys):
    path = write_sweep(tmp_path, n_trials=4)
    assert run_in_process(sweep_args(tmp_path, path, "sweep.sampler=random", "sweep.sampler_seed=1")) == 0
    source = load_study(tmp_path)
    assert source.trials[0].user_attrs.get("baseline")  # the config's own point, trial 0
    ranked = sorted(source.trials, key=lambda t: t.value, reverse=True)[:2]
    expected = [t.number for t in ranked] + ([0] if 0 not in [t.number for t in ranked] else [])
    confirm = ["sweep.top_of=tiny", "sweep.top_k=2", "sweep.study_name=tiny_top", "sweep.seeds=[1,2]"]
    assert run_in_process(sweep_args(tmp_path, path, *confirm, out="top")) == 0
    err = capsys.readouterr().err
    assert f"re-running {len(expected)} trial(s) of study 'tiny' ({expected}: the top 2" in err
    study = load_study(tmp_path, "tiny_top")
    assert states(study) == ["COMPLETE"] * len(expected)
    assert [t.user_attrs["source_trial"] for t in study.trials] == expected
    assert [t.params for t in study.trials] == [source.trials[n].params for n in expected]  # the same points
    assert [bool(t.user_attrs.get("baseline")) for t in study.trials] == [n == 0 for n in expected]
    assert all(t.user_attrs["seeds"] == [1, 2] and len(t.user_attrs["run_ids"]) == 2 for t in study.trials)
    # each re-run trial against the baseline's, seed by seed: python -m diana_lab.compare baseline=<its run id>
    from diana_lab.comparison import compare_runs

    baseline = next(t for t in study.trials if t.user_attrs.get("baseline"))
    c = compare_runs(
        f"sqlite:///{tmp_path}/mlflow.db",
        ["diana_lab"],
        "tags.optuna_study = 'tiny_top'",
        metrics=["eval_spl"],
        curves=[],
        baseline=baseline.user_attrs["run_ids"][0],
    )
    assert len(c.groups) == len(expected)  # one group per trial: its seeds' runs, not the trial's mean run
    assert len(c.paired) == len(expected) - 1
    assert list(c.paired["pairs"]) == [2] * (len(expected) - 1) and set(c.paired["seeds"]) == {"1,2"}
    assert set(c.paired["hosts"]) == {"same"}  # every run of this test trained here
    # a rerun of the same command finds every re-run done: nothing enqueued or trained again
    assert run_in_process(sweep_args(tmp_path, path, *confirm, out="again")) == 0
    assert len(load_study(tmp_path, "tiny_top").trials) == len(expected)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["sweep.top_of=tiny", "sweep.study_name=x"], "needs sweep.seeds"),
        (["sweep.top_of=tiny", "sweep.seeds=[1]"], "need a study of their own"),
        (["sweep.top_of=nope", "sweep.study_name=x", "sweep.seeds=[1]"], "no such study"),
    ],
)
def test_top_of_mistakes_are_named(tmp_path, capsys, extra, message):
    path = write_sweep(tmp_path, n_trials=1)
    assert run_in_process(sweep_args(tmp_path, path, *extra)) == 2
    err = capsys.readouterr().err
    assert message in err and "sweep.top_of" in err and "Traceback" not in err
