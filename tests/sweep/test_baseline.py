"""sweep.baseline: a new study's first trial is the config's own point of the searched space."""

from __future__ import annotations

import pytest

from diana_lab.config import compose
from diana_lab.sweeps.baseline import baseline_values
from diana_lab.sweeps.space import parse_entry

from .helpers import load_study, run_in_process, sweep_args, write_sweep


def test_the_first_trial_is_the_configs_own_values(tmp_path):
    path = write_sweep(tmp_path, n_trials=2)
    assert run_in_process(sweep_args(tmp_path, path, "tracking.enabled=false")) == 0
    first, second = load_study(tmp_path).trials
    cfg = compose([])
    assert first.user_attrs["baseline"] is True and "baseline" not in second.user_attrs
    assert first.params == {
        "algo.learning_rate": pytest.approx(cfg.algo.learning_rate),
        "reward.terms.goal.weight": pytest.approx(cfg.reward.terms.goal.weight),
    }
    assert first.state.name == "COMPLETE" and len(load_study(tmp_path).trials) == 2  # it is one of n_trials


def test_no_baseline_when_asked_or_when_the_config_lies_outside_the_space(tmp_path, capsys):
    path = write_sweep(tmp_path, n_trials=1)
    assert run_in_process(sweep_args(tmp_path, path, "tracking.enabled=false", "sweep.baseline=false")) == 0
    assert "baseline" not in load_study(tmp_path).trials[0].user_attrs
    narrow = (parse_entry("reward.terms.goal.weight", "interval(20, 30)"),)
    assert baseline_values(compose([]), narrow) is None
    assert "reward.terms.goal.weight=10.0 lies outside interval(20, 30)" in capsys.readouterr().err
