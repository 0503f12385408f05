"""``policy=astar_seen``: the planner knows only the ground the rover's own sensor mapped."""

from __future__ import annotations

import numpy as np
import pytest

from diana_lab.config import compose
from diana_lab.core.height_memory import HeightMemory
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.evaluation import AStarOracle, EpisodeSpec, run_episodes
from diana_lab.experts.perceived import SeenMapOracle, sensor_hit
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


def test_sensor_hit_is_the_memorys_known_mask_on_the_cost_map_grid(ridge_env):
    ridge_env.reset(seed=0, options=EPISODE.reset_options())
    for _ in range(3):
        ridge_env.step(ridge_env.action_space.sample())
    memory, grid = ridge_env.sensor.encoder.memory, ridge_env.sampler.costmap
    cx, cy = grid.cell_to_world(np.arange(grid.shape[1]), np.arange(grid.shape[0]))
    expected = memory.heights_at(*np.meshgrid(cx, cy))[1]
    assert 0.05 < expected.mean() < 0.95  # some of the map seen, some not: the test can tell them apart
    np.testing.assert_array_equal(sensor_hit(memory, grid), expected)
    assert not sensor_hit(HeightMemory(0.4, 4.0, 10, 10, 2.0, 2.0), grid).any()


@pytest.mark.parametrize("spec", ["astar_seen"])
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
