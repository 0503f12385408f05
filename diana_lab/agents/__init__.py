"""Policies for the rover's Dict observation and the Hydra-configured construction of SB3 models."""

from diana_lab.agents.extractors import RoverExtractor

__all__ = ["RoverExtractor"]
