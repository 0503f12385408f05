"""The README's sweep figure: which searched keys mattered in a study, and its trials over time.

    python benchmarks/sweep_figures.py --storage docs/studies/reward_shaping.journal --study reward_shaping \
        --out docs/img/reward_study.png

Left: Optuna's fANOVA importances of the searched keys for the objective (of the complete trials; with some tens
of trials a hint, not a measurement). Right: each trial's objective in the order it finished, the baseline trial
(the config's own values, ``sweep.baseline``) marked, pruned trials at their last periodic evaluation.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import optuna
from optuna.importance import FanovaImportanceEvaluator, get_param_importances
from optuna.storages import JournalStorage
from optuna.storages.journal import JournalFileBackend
from optuna.trial import TrialState


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--storage", required=True, help="the study's journal file")
    parser.add_argument("--study", required=True)
    parser.add_argument("--out", required=True, help="the PNG to write")
    parser.add_argument("--seed", type=int, default=0, help="fANOVA's random forest seed")
    args = parser.parse_args()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.load_study(study_name=args.study, storage=JournalStorage(JournalFileBackend(args.storage)))
    importances = get_param_importances(study, evaluator=FanovaImportanceEvaluator(seed=args.seed))
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5), gridspec_kw={"width_ratios": [1, 1.2]})
    keys = list(importances)[::-1]
    left.barh([k.removeprefix("reward.terms.") for k in keys], [importances[k] for k in keys], color="tab:blue")
    left.set(xlabel="fANOVA importance", title=f"{args.study}: what mattered")
    for t in study.get_trials(deepcopy=False):
        if t.state == TrialState.COMPLETE:
            baseline = t.user_attrs.get("baseline", False)
            color, label = ("tab:red", "baseline") if baseline else ("tab:blue", None)
            right.scatter(t.number, t.value, color=color, zorder=3, label=label)
        elif t.state == TrialState.PRUNED and t.intermediate_values:
            last = max(t.intermediate_values)
            right.scatter(t.number, t.intermediate_values[last], color="0.6", marker="x", zorder=2)
    right.set(xlabel="trial", ylabel="objective (final evaluation)", title="trials (x: pruned, at its last evaluation)")
    if any(t.user_attrs.get("baseline") for t in study.trials):
        right.legend(loc="lower right")
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    for key, value in importances.items():
        print(f"{value:.3f}  {key}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
