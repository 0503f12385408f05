"""PhysicsDynamics: spawning, reaching waypoints, and every failure outcome, on the real robot configs."""

import math

import numpy as np
import pybullet as pb
import pytest

from diana_lab.config import ConfigError, build, to_object
from diana_lab.sim.controller import TurnThenDrive
from diana_lab.sim.physics import PhysicsDynamics
from diana_lab.sim.state import RoverState
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import Obstacle, World

ROBOTS = ["jackal", "husky", "rocker_bogie"]


def make(world: World, robot, **overrides) -> tuple[PhysicsDynamics, TurnThenDrive]:
    cfg = to_object("dynamics", {"name": "physics", **overrides})
    return build(cfg, world, robot), TurnThenDrive(cfg.controller, robot)


def robot_cfg(name: str, **overrides):
    return to_object("robot", {**to_object("robot", name).__dict__, **overrides})


def gentle_spot(world: World, near: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The grid sample closest to ``near`` whose surroundings are gentler than 8 degrees."""
    t = world.terrain
    gx, gy = t.cell_xy(*np.meshgrid(np.arange(t.shape[1]), np.arange(t.shape[0])))
    from scipy.ndimage import maximum_filter

    ok = maximum_filter(t.slope_deg, size=7) < 8.0
    d = np.where(ok, np.hypot(gx - near[0], gy - near[1]), np.inf)
    iy, ix = np.unravel_index(np.argmin(d), d.shape)
    return np.array([gx[iy, ix], gy[iy, ix]])


def step(dyn: PhysicsDynamics, seconds: float) -> None:
    scene = dyn.scene()
    for _ in range(round(seconds / dyn.cfg.time_step)):
        pb.stepSimulation(physicsClientId=scene.client)


@pytest.mark.parametrize("world_name", ["flat_world", "hills_world", "mars_yard", "craters_world"])
@pytest.mark.parametrize("name", ROBOTS)
def test_spawns_settled_on_the_ground(request, world_name, name):
    world = request.getfixturevalue(world_name)
    robot = to_object("robot", name)
    xy = gentle_spot(world, (3.0, -4.0))
    dyn, _ = make(world, robot)
    with dyn:
        st = dyn.reset(xy, 0.7)
        assert st.time == 0.0
        ground = float(world.height(*xy))
        assert st.position[2] == pytest.approx(
            ground + robot.base_height * math.cos(math.radians(st.tilt_deg)), abs=0.04
        )
        assert np.linalg.norm(st.xy - xy) < 0.05
        assert st.tilt_deg < 10.0
        assert np.linalg.norm(st.linear_velocity) < 0.05
        step(dyn, 1.0)  # and it stays there: not sinking, not sliding
        later = dyn.state
        assert later.position[2] == pytest.approx(st.position[2], abs=0.005)
        assert np.linalg.norm(later.xy - st.xy) < 0.02


@pytest.mark.parametrize("speed", [0.33, 1.0])
@pytest.mark.parametrize("name", ROBOTS)
def test_reaches_a_3m_waypoint_on_flat(flat_world, name, speed):
    robot = robot_cfg(name, cruise_speed=speed)
    dyn, ctl = make(flat_world, robot)
    with dyn:
        start = dyn.reset(np.array([0.0, 0.0]), math.pi / 2)
        result = dyn.execute(np.array([3.0, 0.0]), ctl)
        end = dyn.state
        assert result.outcome == "reached", result.detail
        assert math.dist(end.xy, (3.0, 0.0)) <= ctl.position_tolerance + 1e-9
        assert abs(end.yaw) < math.radians(15)
        # a 90 degree turn, then 2.8 m: not faster than the commanded speeds, within the controller's limit
        nominal = ctl.nominal_time(3.0, -math.pi / 2)
        assert nominal * 0.95 < result.duration < ctl.time_limit(3.0, -math.pi / 2)
        assert end.time == pytest.approx(start.time + result.duration)
        # traces: start and end samples, the path length is the traced polyline's
        assert len(result.trace_xy) == len(result.trace_tilt_deg) == len(result.trace_rp) >= 2
        np.testing.assert_allclose(result.trace_xy[0], start.xy)
        np.testing.assert_allclose(result.trace_xy[-1], end.xy)
        assert result.path_length == pytest.approx(np.sum(np.linalg.norm(np.diff(result.trace_xy, axis=0), axis=1)))
        assert 2.6 < result.path_length < 3.5
        assert result.max_tilt_deg < 5.0


def test_runs_of_the_same_waypoints_are_identical(flat_world):
    robot = to_object("robot", "jackal")
    finals = []
    for _ in range(2):
        dyn, ctl = make(flat_world, robot)
        with dyn:
            dyn.reset(np.array([0.0, 0.0]), 0.0)
            for wp in ([2.0, 1.0], [0.0, 2.0]):
                dyn.execute(np.array(wp), ctl)
            finals.append(dyn.state.position.copy())
    np.testing.assert_array_equal(finals[0], finals[1])


def test_the_controller_acts_on_the_pose_estimate(flat_world):
    """With an estimate 1 m off in y, the rover parks 1 m beside the waypoint (it believes it is there)."""
    robot = to_object("robot", "jackal")
    dyn, ctl = make(flat_world, robot)
    with dyn:
        dyn.reset(np.array([0.0, 0.0]), 0.0)
        seen = []

        def estimate(state: RoverState) -> tuple[np.ndarray, float]:
            seen.append(state.time)
            return state.xy + np.array([0.0, 1.0]), state.yaw

        result = dyn.execute(np.array([3.0, 1.0]), ctl, estimate)
        assert result.outcome == "reached"
        assert math.dist(dyn.state.xy, (3.0, 0.0)) <= ctl.position_tolerance + 1e-9
        assert len(seen) == len(result.trace_xy)  # once per control period, plus the start
        assert np.allclose(np.diff(seen[1:]), 1.0 / 10.0)


def cliff_world() -> World:
    """A plateau 1.5 m high for x < 0 that drops at 60 degrees to the plain."""
    x = np.linspace(-10.0, 10.0, 201)
    drop = np.clip(x * math.tan(math.radians(60.0)), 0.0, 1.5)
    return World("cliff", Terrain(np.tile(1.5 - drop, (101, 1)), 20.0, 10.0))


@pytest.mark.parametrize("name", ROBOTS)
def test_driving_off_a_steep_slope_tips_over(name):
    robot = to_object("robot", name)
    dyn, ctl = make(cliff_world(), robot)
    with dyn:
        dyn.reset(np.array([-2.0, 0.0]), 0.0)
        result = dyn.execute(np.array([4.0, 0.0]), ctl)
        assert result.outcome == "tipover", result.detail
        assert result.trace_tilt_deg[-1] > robot.tipover_deg
        assert result.trace_xy[-1, 0] > -1.0  # it happened at the edge


def test_hitting_an_obstacle_is_a_collision(flat_world):
    corners = np.array([[x, y, z] for x in (1.8, 2.4) for y in (-0.3, 0.3) for z in (-0.2, 0.5)])
    from scipy.spatial import ConvexHull

    rock = Obstacle(corners, ConvexHull(corners).simplices, name="test_rock")
    world = World("rock", flat_world.terrain, [rock])
    dyn, ctl = make(world, to_object("robot", "jackal"))
    with dyn:
        dyn.reset(np.array([0.0, 0.0]), 0.0)
        result = dyn.execute(np.array([4.0, 0.0]), ctl)
        assert result.outcome == "collision"
        assert "test_rock" in result.detail
        assert 1.8 - 0.3 < result.trace_xy[-1, 0] < 1.8  # the nose (0.25 m ahead) touches the face at x = 1.8


def test_a_wall_it_cannot_climb_gets_it_stuck():
    x = np.linspace(-10.0, 10.0, 201)
    world = World("wall", Terrain(np.tile(np.where(x > 1.0, 0.6, 0.0), (101, 1)), 20.0, 10.0))
    dyn, ctl = make(world, to_object("robot", "jackal"))
    with dyn:
        dyn.reset(np.array([-1.0, 0.0]), 0.0)
        result = dyn.execute(np.array([5.0, 0.0]), ctl)
        assert result.outcome == "stuck", result.detail
        assert dyn.state.position[0] < 1.0
        assert result.duration < ctl.time_limit(6.0, 0.0)


def test_leaving_the_terrain_is_out_of_bounds(flat_world):
    dyn, ctl = make(flat_world, to_object("robot", "jackal"))
    x_max = flat_world.bounds[1]
    with dyn:
        dyn.reset(np.array([x_max - 1.0, 0.0]), 0.0)
        result = dyn.execute(np.array([x_max + 3.0, 0.0]), ctl)
        assert result.outcome == "out_of_bounds"
        assert result.trace_xy[-1, 0] > x_max


def test_the_time_limit_gives_up(flat_world):
    dyn, ctl = make(flat_world, to_object("robot", "jackal"), controller={"timeout_factor": 1.0, "timeout_margin": 0.0})
    with dyn:
        dyn.reset(np.array([0.0, 0.0]), 0.0)
        result = dyn.execute(np.array([0.0, 3.0]), ctl)  # the turn cannot be as fast as the nominal one
        assert result.outcome == "gave_up"
        assert result.duration == pytest.approx(ctl.time_limit(3.0, math.pi / 2), abs=0.11)


@pytest.mark.parametrize("velocity", [[math.nan, 0.0, 0.0], [1e4, 0.0, 0.0]])
def test_a_blown_up_state_is_a_sim_error(flat_world, velocity):
    dyn, ctl = make(flat_world, to_object("robot", "jackal"))
    with dyn:
        dyn.reset(np.array([0.0, 0.0]), 0.0)
        scene = dyn.scene()
        pb.resetBaseVelocity(scene.robot_id, velocity, [0.0, 0.0, 0.0], physicsClientId=scene.client)
        result = dyn.execute(np.array([3.0, 0.0]), ctl)
        assert result.outcome == "sim_error"
        assert np.all(np.isfinite(result.trace_xy))


def test_a_wrong_wheel_joint_name_is_a_config_error(flat_world):
    robot = robot_cfg("husky", wheel_joints_left=["front_left_wheel", "rear_left"])
    with pytest.raises(ConfigError, match=r"robot\.wheel_joints_left"):
        make(flat_world, robot)
