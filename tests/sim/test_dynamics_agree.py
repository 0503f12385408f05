"""The fast kinematic model and PyBullet physics agree where the terrain is gentle (issue: within 0.3 m)."""

import math

import numpy as np
import pytest

from diana_lab.config import build, to_object
from diana_lab.sim.controller import TurnThenDrive


@pytest.mark.parametrize("robot_name", ["jackal", "husky", "rocker_bogie"])
def test_kinematic_and_physics_end_a_waypoint_at_the_same_place_on_hills(hills_world, robot_name):
    robot = to_object("robot", robot_name)
    kin_cfg = to_object("dynamics", "kinematic")
    phy_cfg = to_object("dynamics", "physics")
    kinematic = build(kin_cfg, hills_world, robot)
    physics = build(phy_cfg, hills_world, robot)
    rng = np.random.default_rng(3)
    try:
        for _ in range(4):
            start = rng.uniform(-12, 12, 2)
            yaw = float(rng.uniform(-math.pi, math.pi))
            heading = float(rng.uniform(-math.pi, math.pi))
            waypoint = start + 3.0 * np.array([math.cos(heading), math.sin(heading)])
            ends = []
            for dyn, cfg in ((kinematic, kin_cfg), (physics, phy_cfg)):
                dyn.reset(start, yaw, np.random.default_rng(0))
                result = dyn.execute(waypoint, TurnThenDrive(cfg.controller, robot))
                assert result.outcome == "reached", (dyn.__class__.__name__, result.outcome, result.detail)
                ends.append(dyn.state.xy.copy())
            assert np.linalg.norm(ends[0] - ends[1]) < 0.3
    finally:
        physics.close()
