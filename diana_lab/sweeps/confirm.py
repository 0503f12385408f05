"""Re-run a study's best trials on other training seeds before naming a best (``sweep.top_of=<study>``).

Why: a trial's value is one training seed's score, and the best of 30 noisy scores is biased upwards (the
winner's curse). rl-zoo3's practice, and ours: the top ``sweep.top_k`` trials of the study are re-run on
``sweep.seeds`` (fresh seeds, not the one they were picked on) as a second study in the same storage, whose
trials are those parameter sets enqueued in the order of their first score, then the source study's baseline
trial (the config's own values, ``sweep.baseline``) when it is not among them, as the reference they must beat on
the same seeds; its best, the highest mean over the fresh seeds, is the one to name. Its trials are never pruned
(the point is a full measurement of each).
"""

from __future__ import annotations

import optuna
from optuna.trial import FrozenTrial, TrialState

from diana_lab.core.validation import ConfigError
from diana_lab.sweeps.baseline import BASELINE_ATTR
from diana_lab.sweeps.study import counted

__all__ = ["SOURCE_ATTR", "enqueue_top", "top_trials"]

SOURCE_ATTR = "source_trial"  # user attribute: the number of the trial re-run, in the study it came from


def top_trials(source: optuna.Study, k: int) -> list[FrozenTrial]:
    """The ``k`` best complete trials of ``source``, best first."""
    complete = [t for t in source.get_trials(deepcopy=False) if t.state == TrialState.COMPLETE]
    if not complete:
        raise ConfigError(f"sweep.top_of: study '{source.study_name}' has no complete trial to re-run")
    best_first = source.direction == optuna.study.StudyDirection.MAXIMIZE
    return sorted(complete, key=lambda t: float(t.value), reverse=best_first)[:k]


def enqueue_top(study: optuna.Study, source: optuna.Study, k: int, keys: set[str]) -> list[FrozenTrial]:
    """Enqueue in ``study`` each of ``source``'s top ``k`` trials, and its complete baseline trial, that it does not
    hold yet (a rerun enqueues nothing twice); the trials re-run. ``keys``: the searched keys of this study, which
    must be the source's."""
    top = top_trials(source, k)
    picked = {t.number for t in top}
    baseline = [
        t
        for t in source.get_trials(deepcopy=False)
        if t.state == TrialState.COMPLETE and t.user_attrs.get(BASELINE_ATTR) and t.number not in picked
    ]
    top = top + baseline[:1]
    for t in top:
        if set(t.params) != keys:
            raise ConfigError(
                f"sweep.top_of: trial {t.number} of study '{source.study_name}' searched {sorted(t.params)}, this "
                f"study searches {sorted(keys)}: run it with the source study's sweep file and command line"
            )
    # an interrupted re-run (FAIL, not counted) is enqueued again; a waiting, running or finished one is not
    held = {
        t.user_attrs.get(SOURCE_ATTR)
        for t in study.get_trials(deepcopy=False)
        if t.state == TrialState.WAITING or counted(t)
    }
    for t in top:
        if t.number not in held:
            attrs = {SOURCE_ATTR: t.number, "source_value": t.value}
            if t.user_attrs.get(BASELINE_ATTR):
                attrs[BASELINE_ATTR] = True
            study.enqueue_trial(t.params, user_attrs=attrs)
    return top
