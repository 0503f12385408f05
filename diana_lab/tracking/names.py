"""The metric names every run logs, in one place, so runs of any kind can be compared in one MLflow query.

Evaluation results are ``eval_<key>`` wherever they come from -- the periodic evaluation during training
(step = timesteps, so the metric's history is the learning curve), the final evaluation of a training run
(at the last step, so it is the value MLflow shows for the run) and ``python -m diana_lab.evaluate`` -- so
``tags.algo = 'sac' and metrics.eval_spl > 0.8`` finds them all. A flat name without ``/`` also reads as a
plain column in ``mlflow.search_runs`` (``metrics.eval_spl``) and needs no backticks in a filter.

Training metrics keep the names Stable-Baselines3 gives them (``rollout/ep_rew_mean``, ``time/fps``,
``train/<loss>``) plus the runner's own ``train/reward_<term>`` and ``train/outcome_<outcome>``; they are
forwarded as they are so SB3's console table and MLflow agree. ``docs/metrics.md`` is the table users read;
``tests/compare/test_metric_names.py`` checks that a real run logs nothing the table does not list.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from diana_lab.tracking.params import numeric_metrics

__all__ = ["EVAL_PREFIX", "EXPERIMENT_TAGS", "TAG_GROUPS", "eval_metric", "eval_metrics"]

EVAL_PREFIX = "eval_"

# on every experiment the platform creates: MLflow 3's UI then opens it on its runs, not on the GenAI trace overview
EXPERIMENT_TAGS = {"mlflow.experimentKind": "custom_model_development"}

# the config groups whose chosen option becomes an MLflow tag (filterable in the UI: tags.world = "mars_yard")
TAG_GROUPS = (
    "world",
    "robot",
    "dynamics",
    "sensor",
    "action_space",
    "reward",
    "episode",
    "algo",
    "experiment",
)


def eval_metric(key: str) -> str:
    """The MLflow name of an evaluation summary key: ``spl`` -> ``eval_spl``."""
    return f"{EVAL_PREFIX}{key}"


def eval_metrics(summary: Mapping[str, Any], prefix: str = EVAL_PREFIX) -> dict[str, float]:
    """An evaluation summary as MLflow metrics: ``eval_<key>``, a ``<key>_ci95`` pair as ``_ci95_lo/_hi``."""
    return numeric_metrics(summary, prefix)
