"""The config's own values of the searched keys as a study's first trial (``sweep.baseline``).

Why: the question a study answers is whether anything beats what the config already has (``reward=default``'s
weights, say). With that point enqueued as trial 0, it is measured on the same suite, seed and budget as every
other trial, and the study's table says where it ranks.
"""

from __future__ import annotations

import sys
from typing import Any

import optuna
from omegaconf import OmegaConf
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

from diana_lab.sweeps.space import Param

__all__ = ["BASELINE_ATTR", "baseline_values", "enqueue_baseline"]

BASELINE_ATTR = "baseline"  # user attribute of the enqueued trial


def _inside(param: Param, value: Any) -> bool:
    d = param.distribution
    if isinstance(d, CategoricalDistribution):
        return value in d.choices
    if isinstance(d, FloatDistribution | IntDistribution):
        return isinstance(value, int | float) and not isinstance(value, bool) and d.low <= value <= d.high
    return False


def baseline_values(cfg: Any, params: tuple[Param, ...]) -> dict[str, Any] | None:
    """The composed config's values of ``params``; None (with a note naming the key) when one lies outside its
    searched range, so the point cannot be a trial of this space."""
    values = {p.key: OmegaConf.select(cfg, p.key) for p in params}
    outside = [p for p in params if not _inside(p, values[p.key])]
    if outside:
        p = outside[0]
        print(
            f"note: sweep.baseline: the config's {p.key}={values[p.key]!r} lies outside {p.expression}; no baseline "
            "trial",
            file=sys.stderr,
        )
        return None
    return values


def enqueue_baseline(study: optuna.Study, cfg: Any, params: tuple[Param, ...]) -> bool:
    """Enqueue the baseline point as the study's next trial; whether it was."""
    values = baseline_values(cfg, params)
    if values is None:
        return False
    study.enqueue_trial(values, user_attrs={BASELINE_ATTR: True})
    return True
