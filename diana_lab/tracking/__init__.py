"""Experiment tracking: MLflow runs, config params, and SB3 logger forwarding."""

from diana_lab.tracking.mlflow_run import MlflowTracker, Tracker, resolve_uri
from diana_lab.tracking.writer import MLflowOutputFormat

__all__ = ["MLflowOutputFormat", "MlflowTracker", "Tracker", "resolve_uri"]
