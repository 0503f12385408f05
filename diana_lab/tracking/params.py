"""Turn a resolved config and a summary into what MLflow accepts: flat string params and finite metrics.

MLflow rejects a param value over 6000 characters or a key over 250; a long list (a reward table, an obstacle
list) must not crash a run, so values are truncated with a marker and over-long keys are skipped. Batching is
MLflow's own: ``MlflowClient.log_batch`` splits any number of params, tags and metrics into the batches a store
accepts (100 params or tags, 1000 metrics).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

__all__ = ["MAX_KEY", "MAX_VALUE", "flatten", "numeric_metrics", "truncate"]

MAX_VALUE = 6000  # mlflow.utils.validation.MAX_PARAM_VAL_LENGTH
MAX_KEY = 250  # mlflow.utils.validation.MAX_ENTITY_KEY_LENGTH
ELLIPSIS = "...[truncated]"


def truncate(value: str, limit: int = MAX_VALUE) -> str:
    return value if len(value) <= limit else value[: limit - len(ELLIPSIS)] + ELLIPSIS


def _text(value: Any) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, list | tuple):
        return json.dumps(list(value), default=str)
    return str(value)


def flatten(node: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """``{"algo.learning_rate": "0.0003", ...}``: nested mappings joined with dots, lists as JSON."""
    out: dict[str, str] = {}
    for key, value in node.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            out.update(flatten(value, f"{name}."))
        elif len(name) <= MAX_KEY:
            out[name] = truncate(_text(value) if not isinstance(value, Mapping) else "{}")
    return out


def numeric_metrics(summary: Mapping[str, Any], prefix: str) -> dict[str, float]:
    """Finite numbers of an evaluation summary as ``<prefix><key>``; a 2-item ``<key>_ci95`` becomes
    ``<key>_ci95_lo`` / ``_hi``; strings, NaNs and nested values are left out."""
    out: dict[str, float] = {}
    for key, value in summary.items():
        if isinstance(value, list | tuple) and len(value) == 2:
            for bound, v in zip(("lo", "hi"), value):
                if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
                    out[f"{prefix}{key}_{bound}"] = float(v)
        elif isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
            out[f"{prefix}{key}"] = float(value)
    return out
