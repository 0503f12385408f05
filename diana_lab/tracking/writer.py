"""An SB3 logger output format that forwards every scalar the algorithm logs to MLflow.

SB3 already aggregates rollout reward/length, success rate, FPS and the losses into its logger; forwarding
its dumps (step = timesteps) gives MLflow exactly the numbers of the console table. A key recorded with
``exclude="mlflow"`` is skipped: the runner logs evaluation metrics to MLflow directly, at their own step.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from stable_baselines3.common.logger import KVWriter

from diana_lab.tracking.mlflow_run import Tracker

__all__ = ["MLflowOutputFormat"]


class MLflowOutputFormat(KVWriter):
    def __init__(self, tracker: Tracker) -> None:
        self.tracker = tracker

    def write(self, key_values: dict[str, Any], key_excluded: dict[str, tuple[str, ...]], step: int = 0) -> None:
        metrics: dict[str, float] = {}
        for key, value in key_values.items():
            excluded = key_excluded.get(key) or ()
            if "mlflow" in excluded or isinstance(value, str | bool | np.bool_):
                continue
            if isinstance(value, int | float | np.integer | np.floating) and math.isfinite(float(value)):
                metrics[key] = float(value)
        self.tracker.log_metrics(metrics, step)

    def close(self) -> None:
        pass
