import math

import numpy as np
import pytest

from diana_lab.config import build, to_object
from diana_lab.sim.controller import TurnThenDrive
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import World


def make(world, robot, **overrides):
    cfg = to_object("dynamics", {"name": "kinematic", **overrides})
    return build(cfg, world, robot), TurnThenDrive(cfg.controller, robot)


@pytest.mark.parametrize("robot_name", ["jackal", "husky", "rocker_bogie"])
def test_reaches_a_3m_waypoint_on_flat(flat_world, robot_name):
    robot = to_object("robot", robot_name)
    dyn, ctl = make(flat_world, robot)
    dyn.reset(np.array([0.0, 0.0]), math.pi / 2)
    result = dyn.execute(np.array([3.0, 0.0]), ctl)
    assert result.outcome == "reached"
    assert math.dist(dyn.state.xy, (3.0, 0.0)) <= ctl.position_tolerance + 1e-9
    assert dyn.state.yaw == pytest.approx(0.0, abs=1e-9)
    # turn 90 degrees, then drive 2.8 m at cruise speed
    assert result.duration == pytest.approx(math.pi / 2 / robot.turn_speed + 2.8 / robot.cruise_speed, rel=1e-6)
    assert result.path_length == pytest.approx(3.0 - ctl.position_tolerance)
    assert dyn.state.position[2] == pytest.approx(robot.base_height)


@pytest.mark.parametrize("speed", [0.33, 1.0])
def test_cruise_speed_sets_the_drive_time(flat_world, jackal, speed):
    robot = to_object("robot", {**jackal.__dict__, "cruise_speed": speed})
    dyn, ctl = make(flat_world, robot)
    dyn.reset(np.zeros(2), 0.0)
    result = dyn.execute(np.array([3.2, 0.0]), ctl)
    assert result.duration == pytest.approx(3.0 / speed)


def slope_world(angle_deg: float, size: float = 20.0) -> World:
    x = np.linspace(-size / 2, size / 2, 81)
    grid = np.tile(np.maximum(x, 0.0) * math.tan(math.radians(angle_deg)), (81, 1))  # flat, then a ramp up in +x
    return World("ramp", Terrain(grid, size, size))


def test_pitch_follows_the_terrain_and_sign_convention(jackal):
    world = slope_world(10.0)
    dyn, ctl = make(world, jackal)
    dyn.reset(np.array([3.0, 0.0]), 0.0)  # facing uphill
    assert math.degrees(dyn.state.rpy[1]) == pytest.approx(-10.0, abs=0.1)  # nose up = negative pitch
    dyn.reset(np.array([3.0, 0.0]), math.pi / 2)  # across the slope, uphill on the right
    assert math.degrees(dyn.state.rpy[0]) == pytest.approx(-10.0, abs=0.1)
    assert dyn.state.tilt_deg == pytest.approx(10.0, abs=0.1)


def test_too_steep_to_climb_is_stuck(jackal):
    world = slope_world(jackal.max_slope_deg + 5)
    dyn, ctl = make(world, jackal)
    dyn.reset(np.array([-3.0, 0.0]), 0.0)
    result = dyn.execute(np.array([3.0, 0.0]), ctl)
    assert result.outcome == "stuck"
    assert dyn.state.position[0] < 0.5  # stopped at the foot of the slope


def test_driving_across_a_steep_slope_tips_over(jackal):
    world = slope_world(jackal.tipover_deg + 5)
    dyn, ctl = make(world, jackal)
    dyn.reset(np.array([-2.0, -4.0]), math.pi / 2)
    result = dyn.execute(np.array([-2.0, -1.0]), ctl)  # along the foot: fine
    assert result.outcome == "reached"
    dyn.reset(np.array([-0.5, -4.0]), 0.0)
    result = dyn.execute(np.array([3.0, -4.0]), ctl)  # uphill is too steep, but first: turn across it
    assert result.outcome in ("stuck", "tipover")
    dyn.reset(np.array([-0.5, -4.0]), math.pi / 2)
    result = dyn.execute(np.array([3.0, 3.0]), ctl)  # the turn puts the rover across the slope and onto it
    assert result.outcome in ("tipover", "stuck")
    assert result.max_tilt_deg > 10


def test_collision_with_a_rock(jackal):
    from diana_lab.sim.worlds import _rock

    terrain = Terrain(np.zeros((41, 41)), 20.0, 20.0)
    rock = _rock(np.random.default_rng(0), np.array([3.0, 0.0]), 0.8, 0.0, "rock")
    world = World("rocky", terrain, [rock])
    dyn, ctl = make(world, jackal)
    dyn.reset(np.array([0.0, 0.0]), 0.0)
    result = dyn.execute(np.array([6.0, 0.0]), ctl)
    assert result.outcome == "collision"
    assert 1.5 < dyn.state.position[0] < 3.0
    dyn.reset(np.array([0.0, 2.0]), 0.0)
    assert dyn.execute(np.array([6.0, 2.0]), ctl).outcome == "reached"  # passing beside it is fine


def test_leaving_the_map_is_reported(flat_world, jackal):
    dyn, ctl = make(flat_world, jackal)
    dyn.reset(np.array([18.0, 0.0]), 0.0)
    assert dyn.execute(np.array([23.0, 0.0]), ctl).outcome == "out_of_bounds"


def test_trace_times_sum_to_the_duration(mars_yard, jackal):
    dyn, ctl = make(mars_yard, jackal)
    dyn.reset(np.array([-15.0, 15.0]), 1.0)
    result = dyn.execute(np.array([-13.0, 12.0]), ctl)
    assert result.sample_durations().sum() == pytest.approx(result.duration)
    assert len(result.trace_xy) == len(result.trace_tilt_deg) == len(result.trace_rp)
