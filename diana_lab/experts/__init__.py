"""Planner experts: policies that know the map (the A* oracle) or what the rover's sensor has mapped of it
(``astar_seen``). Baselines for the evaluation and DAgger's labellers for the training, so both import them from
here rather than from each other."""

from diana_lab.experts.actions import waypoint_action
from diana_lab.experts.oracle import AStarOracle, oracle_costmaps, wheel_pitch_deg
from diana_lab.experts.perceived import SeenMapOracle, check_perceivable

__all__ = ["AStarOracle", "SeenMapOracle", "check_perceivable", "oracle_costmaps", "waypoint_action", "wheel_pitch_deg"]
