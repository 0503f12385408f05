"""How short a trial may be: does a study's ranking at a shorter budget agree with its ranking at the full one?

A study run at the full budget with periodic evaluations holds, in each trial, the objective at every shorter
budget too: with a constant learning rate and the same seed, the first B steps of a long run are the run of
budget B, and the periodic evaluation at B is on the same suite as the final one. So one study of a few trials at
the full budget measures every shorter budget at once. Per budget this gives the rank correlation (Spearman's rho,
Kendall's tau) of the trials' values with their full-budget values, and where the trial that is best at that budget
ranks at the full one.

    python -m diana_lab.sweeps.agreement --storage optuna.journal --study reward_shaping_budget --rho 0.8
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import optuna
import pandas as pd
from scipy import stats

from diana_lab.core.validation import ConfigError
from diana_lab.errors import UserError

__all__ = ["budget_agreement", "main", "shortest_agreeing"]


def budget_agreement(study: optuna.Study) -> pd.DataFrame:
    """One row per periodic-evaluation step of the study's complete trials: ``budget`` (steps), ``trials`` (with
    a value there and at the end), ``spearman``, ``kendall``, ``best_rank_at_full`` (1 = also the best at the full
    budget), ``mean`` (the objective's mean at that budget). Maximising or minimising, rank 1 is the best."""
    trials = [t for t in study.get_trials(deepcopy=False) if t.state == optuna.trial.TrialState.COMPLETE]
    if len(trials) < 3:
        raise UserError(
            f"study '{study.study_name}': {len(trials)} complete trial(s); a rank correlation needs 3 or more"
        )
    sign = 1.0 if study.direction == optuna.study.StudyDirection.MAXIMIZE else -1.0
    final = pd.Series({t.number: float(t.value) for t in trials})
    steps = sorted({s for t in trials for s in t.intermediate_values})
    if not steps:
        raise UserError(
            f"study '{study.study_name}': its trials have no periodic evaluations (sweep.eval_every=0); run it with "
            "sweep.eval_every set to the budgets to compare"
        )
    rows = []
    for step in steps:
        at = pd.Series({t.number: t.intermediate_values[step] for t in trials if step in t.intermediate_values})
        if len(at) < 3:
            continue
        full = final[at.index]
        best = (sign * at).idxmax()
        rows.append(
            {
                "budget": int(step),
                "trials": len(at),
                "spearman": float(stats.spearmanr(at, full).statistic),
                "kendall": float(stats.kendalltau(at, full).statistic),
                "best_rank_at_full": int((sign * full).rank(ascending=False, method="min")[best]),
                "mean": float(at.mean()),
            }
        )
    return pd.DataFrame(rows)


def shortest_agreeing(table: pd.DataFrame, rho: float) -> int | None:
    """The shortest budget from which on every longer one's Spearman rho is at least ``rho`` (None: none is)."""
    ok = table["spearman"] >= rho
    for i in range(len(table)):
        if ok.iloc[i:].all():
            return int(table["budget"].iloc[i])
    return None


def _load(storage: str, study_name: str) -> optuna.Study:
    from diana_lab.sweeps.storage import is_rdb, make_storage, resolve_storage

    url = resolve_storage(storage)
    if not is_rdb(url) and not Path(url).is_file():
        raise UserError(f"--storage: no journal file at {url}")
    try:
        return optuna.load_study(study_name=study_name, storage=make_storage(url, 0))
    except KeyError:
        names = [s.study_name for s in optuna.get_all_study_summaries(make_storage(url, 0))]
        raise UserError(f"--study: no study '{study_name}' in {storage} (it holds {names or 'none'})") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m diana_lab.sweeps.agreement", description=__doc__.split("\n")[0])
    parser.add_argument("--storage", default="optuna.journal", help="the study's journal file or RDB URL")
    parser.add_argument("--study", required=True, help="a study run at the full budget with periodic evaluations")
    parser.add_argument("--rho", type=float, default=0.8, help="the Spearman rho a budget must reach (default 0.8)")
    args = parser.parse_args(argv)
    try:
        table = budget_agreement(_load(args.storage, args.study))
    except (UserError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    budget = shortest_agreeing(table, args.rho)
    print(
        f"shortest budget with Spearman rho >= {args.rho} from there on: {budget:,} steps"
        if budget is not None
        else f"no budget reaches Spearman rho >= {args.rho} at every longer one"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
