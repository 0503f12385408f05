"""``policy=astar_perceived`` / ``astar_seen``: the planners know only what the rover's own sensor mapped."""

from __future__ import annotations

import numpy as np
import pytest

from diana_lab.config import compose
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.evaluation import AStarOracle, EpisodeSpec, StraightLine, run_episodes
from diana_lab.evaluation.perceived import PerceivedMapOracle, SeenMapOracle, perceived_heights, sensor_hit
from diana_lab.height_memory import HeightMemory
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import World
from tests.presets import CAMERA_SQUARE

EPISODE = EpisodeSpec(np.array([-4.0, 0.5]), 0.3, np.array([4.0, -0.5]), seed=3)


@pytest.fixture(scope="module")
def ridge_env():
    """Flat 20 m ground with a 0.6 m high, 1 m thick ridge across the way (x = 0, |y| < 5): terrain, not an
    obstacle body, so only the heights the lidar returns can tell the planner about it."""
    x = np.linspace(-10.0, 10.0, 81)
    gx, gy = np.meshgrid(x, x)
    heights = np.where((np.abs(gx) < 0.5) & (np.abs(gy) < 5.0), 0.6, 0.0)
    world = World("ridge", Terrain(heights, 20.0, 20.0), [])
    env = RoverNavEnv(config=compose(["+experiment=reference", "episode.max_steps=60"]), world_instance=world)
    yield env
    env.close()


def test_it_knows_what_the_lidar_hit_and_not_the_ground_the_ridge_hides(ridge_env):
    oracle = PerceivedMapOracle()
    ridge_env.reset(seed=0, options=EPISODE.reset_options())
    oracle.reset(ridge_env)
    grid = ridge_env.sampler.costmap
    cx, cy = grid.cell_to_world(np.arange(grid.shape[1]), np.arange(grid.shape[0]))
    gx, gy = np.meshgrid(cx, cy)
    front = (gx > -3.0) & (gx < -1.0) & (np.abs(gy) < 3.0)
    behind = (gx > 0.7) & (gx < 2.5) & (np.abs(gy) < 3.0)
    assert oracle.known is not None
    assert oracle._hit[front].mean() > 0.9  # the open ground ahead of it
    assert oracle._hit[behind].mean() < 0.1  # in the ridge's shadow
    np.testing.assert_allclose(oracle.perceived[front & oracle._hit], 0.0, atol=0.02)  # flat, as seen
    # the cost map it plans on bans the ridge's face it saw, and the shadow costs the least (unknown)
    face = (np.abs(gx + 0.6) < 0.3) & (np.abs(gy) < 3.0)
    assert np.isinf(oracle.known.cost[face]).mean() > 0.5
    assert np.all(oracle.known.cost[behind & ~oracle._hit] == np.min(oracle.known.cost))
    # the ridge's far face is as steep as its near one, but unseen: the true-terrain oracle bans it, this
    # one cannot know it yet
    back = (np.abs(gx - 0.6) < 0.3) & (np.abs(gy) < 3.0)
    assert oracle._hit[back].mean() < 0.5
    banned = back & np.isinf(AStarOracle().costmaps(ridge_env)[0].cost)
    assert banned.sum() > 10
    assert np.isinf(oracle.known.cost[banned]).mean() < 0.5


def test_it_drives_round_the_ridge_that_the_straight_line_tips_over_on(ridge_env):
    straight = run_episodes(StraightLine(), ridge_env, [EPISODE])[0]
    assert straight.loc[0, "outcome"] in ("tipover", "stuck")
    df, traces = run_episodes(PerceivedMapOracle(), ridge_env, [EPISODE])
    assert df.loc[0, "outcome"] == "success", df.iloc[0].to_dict()
    assert np.abs(traces[0].xy[:, 1]).max() > 5.0  # round an end of the 10 m ridge


def test_perceived_heights_interpolate_seen_cells_and_leave_the_rest_unknown():
    memory = HeightMemory(0.4, 4.0, 10, 10, 2.0, 2.0)
    x = np.linspace(-2.0, 2.0, 81)
    gx, gy = np.meshgrid(x, x)
    plane = 0.1 * gx - 0.05 * gy
    seen = gx < 0.5  # a plane seen only where x < 0.5
    memory.update(np.column_stack([gx[seen], gy[seen], plane[seen]]), np.zeros(2))
    px, py = np.meshgrid(np.linspace(-1.5, 0.0, 7), np.linspace(-1.5, 1.5, 7))
    height, known = perceived_heights(memory, px, py)
    assert known.all()
    # max height per 0.4 m cell, then bilinear between cell centres: the plane shifted up by at most the
    # rise over one cell's upper half (0.1 * 0.2 + 0.05 * 0.2 = 0.03 m)
    err = height - (0.1 * px - 0.05 * py)
    assert np.all((err >= -1e-6) & (err <= 0.03 + 1e-6)), err
    far_x, far_y = np.array([1.5, 3.0, 9.0]), np.array([0.0, 0.0, 0.0])  # unseen, unseen, off the map
    height, known = perceived_heights(memory, far_x, far_y)
    assert not known.any() and np.isnan(height).all()
    empty = HeightMemory(0.4, 4.0, 10, 10, 2.0, 2.0)
    assert not perceived_heights(empty, px, py)[1].any()


def test_sensor_hit_is_perceived_heights_known_mask_on_the_cost_map_grid(ridge_env):
    ridge_env.reset(seed=0, options=EPISODE.reset_options())
    for _ in range(3):
        ridge_env.step(ridge_env.action_space.sample())
    memory, grid = ridge_env.sensor.encoder.memory, ridge_env.sampler.costmap
    cx, cy = grid.cell_to_world(np.arange(grid.shape[1]), np.arange(grid.shape[0]))
    expected = perceived_heights(memory, *np.meshgrid(cx, cy))[1]
    assert 0.05 < expected.mean() < 0.95  # some of the map seen, some not: the test can tell them apart
    np.testing.assert_array_equal(sensor_hit(memory, grid), expected)
    assert not sensor_hit(HeightMemory(0.4, 4.0, 10, 10, 2.0, 2.0), grid).any()


@pytest.mark.parametrize("spec", ["astar_perceived", "astar_seen"])
def test_it_refuses_a_sensor_that_keeps_no_map(spec):
    from diana_lab.cli import UserError
    from diana_lab.evaluation.loading import load_policy

    with pytest.raises(UserError, match=rf"policy={spec}.*sensor\.elevation_map\.memory=true"):
        load_policy(spec, compose(CAMERA_SQUARE), None)
    assert load_policy(spec, compose(["+experiment=reference"]), None).label == spec


def test_astar_seen_knows_the_true_cost_of_the_cells_the_lidar_hit_and_nothing_else(ridge_env):
    oracle = SeenMapOracle()
    ridge_env.reset(seed=0, options=EPISODE.reset_options())
    oracle.reset(ridge_env)
    grid = ridge_env.sampler.costmap
    hit = sensor_hit(ridge_env.sensor.encoder.memory, grid)
    truth = AStarOracle().costmaps(ridge_env)[0].cost
    known = oracle.knowledge(ridge_env, grid)
    assert known.any() and not (known & ~hit).any()  # nothing the sensor did not hit...
    far = np.hypot(*np.meshgrid(*grid.cell_to_world(np.arange(grid.shape[1]), np.arange(grid.shape[0])))) > 16.0
    assert not (known & far).any()  # ...nor beyond the 12 m horizon (the rover starts 4 m from the centre)
    np.testing.assert_array_equal(oracle.known.cost[known], truth[known])  # the truth where it knows
    assert np.all(oracle.known.cost[~known] == np.min(truth[np.isfinite(truth)]))  # the cheapest elsewhere
    # the near face of the ridge is banned (seen), the far face is not (in its shadow), unlike the truth
    gx, gy = np.meshgrid(*grid.cell_to_world(np.arange(grid.shape[1]), np.arange(grid.shape[0])))
    face, back = (np.abs(gx + 0.6) < 0.3) & (np.abs(gy) < 3.0), (np.abs(gx - 0.6) < 0.3) & (np.abs(gy) < 3.0)
    banned_face, banned_back = face & np.isinf(truth), back & np.isinf(truth)
    assert banned_face.sum() > 10 and np.isinf(oracle.known.cost[banned_face]).mean() > 0.9
    assert banned_back.sum() > 10 and np.isinf(oracle.known.cost[banned_back]).mean() < 0.5


def test_astar_seen_drives_round_the_ridge(ridge_env):
    df, traces = run_episodes(SeenMapOracle(), ridge_env, [EPISODE])
    assert df.loc[0, "outcome"] == "success", df.iloc[0].to_dict()
    assert np.abs(traces[0].xy[:, 1]).max() > 5.0
