"""Actions an agent (or a buggy policy) can send, in both dynamics: the defined behaviour of docs/reliability.md.

* NaN or infinite components (or a wrong shape) raise ``ActionError`` before anything moves; so does a
  candidate index that is not one integer in ``[0, n)`` (``action_space=discrete``);
* values beyond [-1, 1] are clipped: a huge action drives exactly like the edge of the action space;
* a waypoint beyond the map is clamped inside it (robot radius + ``episode.map_margin``), so no action
  drives the rover off the map;
* a waypoint inside an obstacle is driven towards and ends the episode as ``collision``.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from diana_lab.config import build, compose, to_object
from diana_lab.envs.action_spaces import ActionError
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import Obstacle, World
from tests.presets import CAMERA_SQUARE

DYNAMICS = ["kinematic", "physics"]
SIZE = 20.0  # a 20 m flat world: bounds +-10 m
SMALL = [
    *CAMERA_SQUARE,
    "world=flat",
    f"world.size_x={SIZE}",
    f"world.size_y={SIZE}",
    "sensor.width=16",
    "sensor.height=12",
]


@functools.cache
def flat_world() -> World:
    """One world (and so one cost map) for every env of this module."""
    return build(to_object("world", compose(SMALL).world))


def make_env(dynamics: str, world: World | None = None, *overrides: str) -> RoverNavEnv:
    cfg = compose([*SMALL, f"dynamics={dynamics}", *overrides])
    return RoverNavEnv(config=cfg, world_instance=world or flat_world())


def box_world() -> World:
    """Flat ground with a 1 m x 2 m x 0.6 m box from x = 2.5 to 3.5 m across the x axis."""
    corners = np.array([[x, y, z] for x in (2.5, 3.5) for y in (-1.0, 1.0) for z in (0.0, 0.6)])
    box = Obstacle(corners, ConvexHull(corners).simplices, name="box", convex=True)
    n = round(SIZE / 0.25) + 1
    return World("box", Terrain(np.zeros((n, n)), SIZE, SIZE), [box])


def reset_at(env: RoverNavEnv, start: tuple[float, float], goal: tuple[float, float] = (-8.0, -8.0)) -> None:
    env.reset(seed=0, options={"start": start, "goal": goal, "yaw": 0.0})


@pytest.fixture(scope="module", params=DYNAMICS)
def env(request: pytest.FixtureRequest):
    e = make_env(request.param)
    yield e
    e.close()


@pytest.mark.parametrize(
    "action",
    [[np.nan, 0.0], [0.0, np.nan], [np.inf, 0.0], [0.0, -np.inf], [np.nan, np.inf]],
    ids=["nan-x", "nan-y", "inf-x", "neg-inf-y", "nan-and-inf"],
)
def test_non_finite_actions_raise_before_anything_moves(env: RoverNavEnv, action: list[float]) -> None:
    reset_at(env, (0.0, 0.0))
    before = env.dynamics.state.copy()
    with pytest.raises(ActionError, match="finite"):
        env.step(np.array(action, dtype=np.float32))
    after = env.dynamics.state
    np.testing.assert_array_equal(after.position, before.position)
    assert after.time == before.time
    _, _, _, _, info = env.step(np.array([0.5, 0.0], dtype=np.float32))  # the episode goes on
    assert info["steps"] == 1


@pytest.mark.parametrize("action", [[1.0], [1.0, 0.0, 0.0], [[1.0, 0.0]]], ids=["1", "3", "1x2"])
def test_wrongly_shaped_actions_raise(env: RoverNavEnv, action: list) -> None:
    reset_at(env, (0.0, 0.0))
    with pytest.raises(ActionError, match="shape"):
        env.step(np.array(action, dtype=np.float32))


@pytest.mark.parametrize("dynamics", DYNAMICS)
def test_bad_candidate_indices_raise_before_anything_moves(dynamics: str) -> None:
    e = make_env(dynamics, None, "action_space=discrete")
    try:
        reset_at(e, (0.0, 0.0))
        before = e.dynamics.state.copy()
        for action in (48, -1, np.float32(2.0), np.nan, np.array([1, 2]), np.array([0.5, 0.0], dtype=np.float32)):
            with pytest.raises(ActionError, match="action"):
                e.step(action)
        np.testing.assert_array_equal(e.dynamics.state.position, before.position)
        assert e.dynamics.state.time == before.time
        _, _, _, _, info = e.step(np.int64(47))  # the episode goes on
        assert info["steps"] == 1
    finally:
        e.close()


@pytest.mark.parametrize("dynamics", DYNAMICS)
@pytest.mark.parametrize(
    ("huge", "edge"),
    [([1e9, -1e30], [1.0, -1.0]), ([np.finfo(np.float32).max, 0.25], [1.0, 0.25]), ([-3.0, 2.0], [-1.0, 1.0])],
    ids=["1e9", "float32-max", "3x"],
)
def test_huge_actions_drive_like_the_edge_of_the_action_space(
    dynamics: str, huge: list[float], edge: list[float]
) -> None:
    results = []
    for action in (huge, edge):  # a fresh env each: the same state before the step; 1 m waypoints (fast)
        e = make_env(dynamics, None, "action_space.size=2")
        try:
            reset_at(e, (0.0, 0.0))
            _, reward, _, _, info = e.step(np.array(action, dtype=np.float32))
            results.append((info["waypoint"], info["position"], reward))
        finally:
            e.close()
    (wp_huge, pos_huge, r_huge), (wp_edge, pos_edge, r_edge) = results
    np.testing.assert_array_equal(wp_huge, wp_edge)
    np.testing.assert_allclose(pos_huge, pos_edge, atol=1e-6)
    assert r_huge == pytest.approx(r_edge)


@pytest.mark.parametrize(
    ("start", "action"),
    [((8.0, 0.0), [1.0, 0.0]), ((8.0, 8.0), [1.0, 1.0]), ((-8.0, -7.0), [-1.0, -1.0])],
    ids=["east-edge", "north-east-corner", "south-west-corner"],
)
def test_waypoints_beyond_the_map_are_clamped_inside_it(
    env: RoverNavEnv, start: tuple[float, float], action: list[float]
) -> None:
    # the rover faces +x: the square's corners then point beyond the map on the side it starts near
    reset_at(env, start, goal=(0.0, 0.0))
    unclamped = env.pose_estimate.xy + env.mapping.offset(np.array(action), env.pose_estimate.yaw)
    limit = SIZE / 2 - env.robot.radius - env.episode_cfg.map_margin
    assert np.max(np.abs(unclamped)) > SIZE / 2  # the action really asks for a point off the map
    _, _, _, _, info = env.step(np.array(action, dtype=np.float32))
    assert np.all(np.abs(info["waypoint"]) <= limit + 1e-9)
    assert np.any(np.isclose(np.abs(info["waypoint"]), limit))
    assert info.get("outcome") != "out_of_bounds"
    assert np.all(np.abs(info["position"][:2]) < SIZE / 2)


@pytest.mark.parametrize("dynamics", DYNAMICS)
def test_a_waypoint_inside_an_obstacle_ends_in_collision(dynamics: str) -> None:
    e = make_env(dynamics, box_world())
    try:
        e.reset(seed=0, options={"start": (0.0, 0.0), "goal": (8.0, 0.0), "yaw": 0.0})
        _, reward, terminated, truncated, info = e.step(np.array([1.0, 0.0], dtype=np.float32))  # (3.5, 0)
    finally:
        e.close()
    assert (terminated, truncated, info["outcome"]) == (True, False, "collision"), info.get("waypoint_outcome")
    assert info["reward_terms"]["collision"] < 0
    assert info["position"][0] < 3.5  # stopped at the box, not driven through it
