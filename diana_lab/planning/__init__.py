"""Traversability and shortest paths: the cost map, Dijkstra/any-angle planning, SPL's reference length.

Used by the episode sampler (start and goal in one connected component, so a path exists), by evaluation
(SPL's shortest path length) and by the ``astar`` oracle baseline (waypoints along the planned path).
"""

from diana_lab.planning.costmap import CostMap, CostMapConfig, build_costmap, shared_costmap
from diana_lab.planning.goal_distance import GoalDistance
from diana_lab.planning.hazards import HazardLayers, terrain_hazards
from diana_lab.planning.paths import (
    Path,
    WaypointChoice,
    choose_waypoint,
    next_waypoint,
    plan,
    shortest_path_length,
    simplify,
)

__all__ = [
    "CostMap",
    "CostMapConfig",
    "GoalDistance",
    "HazardLayers",
    "Path",
    "WaypointChoice",
    "build_costmap",
    "choose_waypoint",
    "next_waypoint",
    "plan",
    "shared_costmap",
    "shortest_path_length",
    "simplify",
    "terrain_hazards",
]
