"""The experiment runner behind ``python -m diana_lab``: train, checkpoint, evaluate and track one agent."""

from diana_lab.training.context import RunContext, StopRun
from diana_lab.training.runner import train
from diana_lab.training.summary import TrainResult

__all__ = ["RunContext", "StopRun", "TrainResult", "train"]
