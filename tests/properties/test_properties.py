"""Property-based tests (hypothesis): invariants over random actions, poses, worlds and seeds."""

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from diana_lab.config import build, to_object
from diana_lab.envs.action_spaces import WaypointMapping
from diana_lab.envs.rewards import RewardContext, RewardManager
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.sim.state import WaypointResult
from tests.presets import CAMERA_SQUARE

finite = st.floats(min_value=-1e12, max_value=1e12, allow_nan=False, allow_infinity=False)
angles = st.floats(min_value=-4 * math.pi, max_value=4 * math.pi, allow_nan=False)
FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@FAST
@given(
    action=st.tuples(finite, finite),
    yaw=angles,
    shape=st.sampled_from(["square", "circle"]),
    frame=st.sampled_from(["rover", "world"]),
)
def test_waypoints_stay_inside_their_shape(action, yaw, shape, frame):
    mapping = WaypointMapping(to_object("action_space", {"name": shape, "shape": shape, "frame": frame}))
    offset = mapping.offset(np.array(action), yaw)
    assert np.all(np.isfinite(offset))
    if frame == "rover":  # back into the shape's own axes
        c, s = math.cos(yaw), math.sin(yaw)
        offset = np.array([c * offset[0] + s * offset[1], -s * offset[0] + c * offset[1]])
    if shape == "square":
        assert np.all(np.abs(offset) <= 3.5 + 1e-9)
    else:
        assert math.hypot(*offset) <= 4.0 + 1e-9


@FAST
@given(
    offset=st.tuples(finite, finite),
    yaw=angles,
    frame=st.sampled_from(["rover", "world"]),
    headings=st.integers(2, 40),
    distances=st.lists(st.floats(0.05, 3.5), min_size=1, max_size=5, unique=True).map(sorted),
)
def test_discrete_actions_are_valid_indices_whose_waypoints_stay_inside_the_square(
    offset, yaw, frame, headings, distances
):
    cfg = {"name": "discrete", "shape": "discrete", "frame": frame, "headings": headings, "distances": distances}
    mapping = WaypointMapping(to_object("action_space", cfg))
    action = mapping.action_for(np.array(offset), yaw)
    assert mapping.space.contains(action)
    waypoint = mapping.offset(action, yaw)
    assert np.all(np.isfinite(waypoint))
    assert min(distances) - 1e-9 <= math.hypot(*waypoint) <= max(distances) + 1e-9  # inside the 7 m square


@FAST
@given(
    prev=st.floats(0, 100),
    dist=st.floats(0, 100),
    heading=angles,
    rp=st.lists(st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)), min_size=1, max_size=20),
    outcome=st.sampled_from([None, "success", "collision", "tipover", "out_of_bounds", "timeout", "stuck"]),
    waypoint=st.sampled_from(["reached", "gave_up", "stuck", "collision"]),
    duration=st.floats(0, 1000),
    preset=st.sampled_from(["default", "paper"]),
)
def test_reward_terms_are_finite_and_bounded(prev, dist, heading, rp, outcome, waypoint, duration, preset):
    manager = RewardManager(to_object("reward", preset))
    rp = np.array(rp)
    result = WaypointResult(waypoint, duration, 1.0, np.zeros((len(rp), 2)), np.zeros(len(rp)), rp)
    total, terms = manager(RewardContext(prev, dist, heading, result, outcome, 1))
    assert math.isfinite(total)
    weights = {name: abs(w) for name, _, w, _ in manager.terms}
    for name, value in terms.items():
        # every term is at most |weight| x (the largest raw value it can take: 100 m progress, 1.5 rad tilt...)
        assert abs(value) <= weights[name] * max(100.0, duration) + 1e-9, name


_ENVS: dict = {}


def env_for(world: str, encoding: str) -> RoverNavEnv:
    key = (world, encoding)
    if key not in _ENVS:
        from diana_lab.config import compose

        # the camera (its encodings of every kind) and the square action space the hypothesis' actions drive
        _ENVS[key] = RoverNavEnv(config=compose([*CAMERA_SQUARE, f"world={world}", f"sensor.encoding={encoding}"]))
    return _ENVS[key]


@settings(max_examples=40, deadline=None)
@given(
    world=st.sampled_from(["mars_yard", "hills", "craters"]),
    encoding=st.sampled_from(["depth_image", "elevation_map", "points"]),
    seed=st.integers(0, 2**31 - 1),
    actions=st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1)), max_size=4),
)
def test_observations_stay_inside_their_spaces(world, encoding, seed, actions):
    env = env_for(world, encoding)
    obs, _ = env.reset(seed=seed)
    assert env.observation_space.contains(obs)
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(np.array(action, dtype=np.float32))
        assert env.observation_space.contains(obs) and math.isfinite(reward)
        if terminated or truncated:
            break


@settings(max_examples=40, deadline=None)
@given(
    x=st.floats(-24, 24),
    y=st.floats(-24, 24),
    yaw=angles,
    roll=st.floats(-0.6, 0.6),
    pitch=st.floats(-0.6, 0.6),
    encoding=st.sampled_from(["depth_image", "elevation_map", "points"]),
)
def test_encoders_inside_their_space_on_random_poses(x, y, yaw, roll, pitch, encoding):
    env = env_for("mars_yard", encoding)
    sensor = env.sensor
    z = float(env.world.height(x, y)) + 0.1
    obs = sensor.observe(np.array([x, y, z]), np.array([roll, pitch, yaw]))
    assert sensor.observation_space.contains(obs)


def test_world_builds_are_deterministic_per_seed():
    a = build(to_object("world", {"name": "hills", "seed": 5}))
    b = build(to_object("world", {"name": "hills", "seed": 5}))
    np.testing.assert_array_equal(a.terrain.heights, b.terrain.heights)
