"""Budget agreement: ranks at each periodic evaluation against the full budget's."""

from __future__ import annotations

import optuna
import pytest
from optuna.distributions import FloatDistribution
from optuna.storages import JournalStorage
from optuna.storages.journal import JournalFileBackend

from diana_lab.errors import UserError
from diana_lab.sweeps.agreement import budget_agreement, main, shortest_agreeing


def _study(curves: list[dict[int, float]], finals: list[float], direction="maximize", storage=None) -> optuna.Study:
    study = optuna.create_study(direction=direction, storage=storage, study_name="budget")
    for i, (curve, final) in enumerate(zip(curves, finals)):
        study.add_trial(
            optuna.trial.create_trial(
                params={"w": float(i)},
                distributions={"w": FloatDistribution(0, 10)},
                value=final,
                intermediate_values=curve,
            )
        )
    return study


def test_a_budget_that_keeps_the_order_agrees_and_one_that_reverses_it_does_not():
    finals = [0.1, 0.2, 0.3, 0.4, 0.5]
    curves = [{100: f, 200: -f, 300: f + 0.01} for f in finals]  # step 200 ranks them backwards
    table = budget_agreement(_study(curves, finals)).set_index("budget")
    assert table.loc[100, "spearman"] == pytest.approx(1.0) and table.loc[100, "kendall"] == pytest.approx(1.0)
    assert table.loc[200, "spearman"] == pytest.approx(-1.0)
    assert table.loc[100, "best_rank_at_full"] == 1 and table.loc[200, "best_rank_at_full"] == 5
    assert table.loc[100, "trials"] == 5
    assert shortest_agreeing(table.reset_index(), 0.8) == 300  # 200 breaks the run of agreeing budgets


def test_minimising_studies_rank_the_smallest_first():
    finals = [3.0, 2.0, 1.0]
    curves = [{10: f} for f in finals]
    table = budget_agreement(_study(curves, finals, direction="minimize"))
    assert table["best_rank_at_full"].tolist() == [1] and table["spearman"].tolist() == [pytest.approx(1.0)]


def test_too_few_trials_or_no_periodic_evaluations_are_explained():
    with pytest.raises(UserError, match="3 or more"):
        budget_agreement(_study([{1: 0.1}, {1: 0.2}], [0.1, 0.2]))
    with pytest.raises(UserError, match=r"sweep\.eval_every"):
        budget_agreement(_study([{}, {}, {}], [0.1, 0.2, 0.3]))


def test_command_prints_the_table_and_names_a_missing_study(tmp_path, capsys):
    journal = tmp_path / "s.journal"
    storage = JournalStorage(JournalFileBackend(str(journal)))
    _study([{5: f} for f in (0.1, 0.3, 0.2)], [0.1, 0.3, 0.2], storage=storage)
    assert main(["--storage", str(journal), "--study", "budget"]) == 0
    out = capsys.readouterr().out
    assert "spearman" in out and "shortest budget with Spearman rho >= 0.8 from there on: 5 steps" in out
    assert main(["--storage", str(journal), "--study", "nope"]) == 2
    assert "no study 'nope'" in capsys.readouterr().err
    assert main(["--storage", str(tmp_path / "missing.journal"), "--study", "budget"]) == 2
    assert "no journal file" in capsys.readouterr().err
