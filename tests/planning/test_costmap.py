"""Cost map: hazards against the robot's limits, obstacle inflation, border, components, config checks."""

from __future__ import annotations

import numpy as np
import pytest

from diana_lab.config import ConfigError
from diana_lab.planning import CostMapConfig, build_costmap
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import World
from tests.planning.helpers import box, flat_world, ramp_world


def test_flat_world_is_traversable_inside_the_border(jackal):
    cm = build_costmap(flat_world(), jackal)
    gx, gy = cm.cell_to_world(*np.meshgrid(np.arange(cm.shape[1]), np.arange(cm.shape[0])))
    interior = (np.abs(gx) <= 10.0 - jackal.radius) & (np.abs(gy) <= 10.0 - jackal.radius)
    assert np.all(cm.cost[interior] == 1.0)
    assert np.all(np.isinf(cm.cost[~interior]))
    assert cm.n_components == 1
    assert cm.largest_component_mask.sum() == interior.sum()


def test_cell_coordinates_round_trip(jackal):
    cm = build_costmap(flat_world(), jackal)
    ix, iy = np.array([0, 7, 100]), np.array([3, 50, 0])
    x, y = cm.cell_to_world(ix, iy)
    assert np.allclose(x, -10.0 + 0.2 * ix) and np.allclose(y, -10.0 + 0.2 * iy)
    back = cm.world_to_cell(x + 0.09, y - 0.09)
    assert np.array_equal(back[0], ix) and np.array_equal(back[1], iy)
    assert not cm.traversable(50.0, 0.0) and cm.component_at(50.0, 0.0) == 0


@pytest.mark.parametrize(("slope_deg", "passable"), [(10.0, True), (20.0, True), (23.0, False), (30.0, False)])
def test_slope_against_robot_limit(jackal, slope_deg, passable):
    cm = build_costmap(ramp_world(slope_deg), jackal)
    limit = jackal.max_slope_deg - CostMapConfig().slope_margin_deg  # 25 - 3 degrees
    centre = cm.cost[cm.shape[0] // 2, cm.shape[1] // 2]
    assert np.isfinite(centre) == passable
    assert np.all(np.isfinite(cm.cost[~cm.layers["border"]]) == passable)  # a plane is the same everywhere
    if passable:  # gentle slopes cost more than flat ground, in proportion to the slope
        assert centre == pytest.approx(1.0 + slope_deg / limit, abs=0.01)
        assert cm.layers["step"].max() < 1e-9  # a plane has no steps however steep it is
    no_margin = build_costmap(ramp_world(slope_deg), jackal, CostMapConfig(slope_margin_deg=0.0))
    assert np.isfinite(no_margin.cost[50, 50]) == (slope_deg < jackal.max_slope_deg)


def test_step_is_detected_but_smooth_slope_is_not(jackal):
    n = 101
    h = np.zeros((n, n))
    h[:, 60:] = 0.15  # a 15 cm ledge along x = 2 m, taller than the jackal's 8 cm step limit
    cm = build_costmap(World("ledge", Terrain(h, 20.0, 20.0)), jackal)
    assert not cm.traversable(2.0, 0.0)
    assert cm.traversable(-3.0, 0.0) and cm.traversable(5.0, 0.0)
    assert cm.component_at(-3.0, 0.0) != cm.component_at(5.0, 0.0)
    low = build_costmap(World("ledge", Terrain(np.where(h > 0, 0.04, 0.0), 20.0, 20.0)), jackal)
    assert low.traversable(2.0, 0.0) and low.cost_at(2.0, 0.0) > 1.0


def test_inflation_radius_is_the_robot_footprint(jackal):
    world = flat_world(obstacles=[box(-0.25, 0.25, -0.3, 0.3, 0.5)])
    cm = build_costmap(world, jackal)
    ix, iy = np.meshgrid(np.arange(cm.shape[1]), np.arange(cm.shape[0]))
    x, y = cm.cell_to_world(ix, iy)
    # exact distance from every cell centre to the box; cell centres are where the planner puts the robot
    d = np.hypot(np.maximum(np.abs(x) - 0.25, 0.0), np.maximum(np.abs(y) - 0.3, 0.0))
    near = d < 3.0
    lethal = ~cm.free
    assert np.all(lethal[near & (d < jackal.radius)])
    # beyond the radius, half a cell (paths run anywhere in a free cell) and the raster's quantisation
    # (one obstacle_resolution), everything is free
    assert np.all(~lethal[near & (d > jackal.radius + 0.5 * cm.resolution + world.obstacle_resolution)])
    assert np.array_equal(cm.layers["obstacle"][near], lethal[near])  # the band, not the flat ground, did it
    wider = build_costmap(world, jackal, CostMapConfig(inflation_margin=0.5))
    assert np.all(~wider.free[d < jackal.radius + 0.5])


def test_low_obstacles_are_ignored(jackal):
    world = flat_world(obstacles=[box(-0.25, 0.25, -0.25, 0.25, 0.03)])  # under the 6.5 cm clearance
    assert build_costmap(world, jackal).traversable(0.0, 0.0)
    assert not build_costmap(world, jackal, CostMapConfig(obstacle_height=0.02)).traversable(0.0, 0.0)


def test_wall_splits_the_world_into_components(jackal):
    cm = build_costmap(flat_world(obstacles=[box(-11.0, 11.0, -0.2, 0.2, 1.0)]), jackal)
    north, south = cm.component_at(0.0, 5.0), cm.component_at(0.0, -5.0)
    assert north > 0 and south > 0 and north != south
    assert cm.n_components == 2
    assert cm.largest_component_mask.sum() == pytest.approx(cm.free.sum() / 2, rel=0.02)


def test_resolution_is_coarsened_to_the_cell_limit(jackal):
    world = flat_world(size=100.0, spacing=0.1)
    cm = build_costmap(world, jackal)
    assert max(cm.shape) <= 300 and cm.resolution == pytest.approx(100.0 / 299)
    fine = build_costmap(world, jackal, CostMapConfig(max_cells=2000))
    assert fine.resolution == pytest.approx(0.1) and fine.shape == (1001, 1001)
    explicit = build_costmap(world, jackal, CostMapConfig(resolution=0.5))
    assert explicit.shape == (201, 201)


def test_coarse_cells_keep_the_worst_hazard(jackal):
    n = 201
    h = np.zeros((n, n))
    h[100:103, 100:103] = 0.3  # a 30 cm bump of 0.3 m x 0.3 m
    world = World("bump", Terrain(h, 20.0, 20.0))
    for res in (None, 0.35):
        cm = build_costmap(world, jackal, CostMapConfig(resolution=res))
        assert not cm.traversable(0.1, 0.1)
        assert cm.traversable(3.0, 3.0)


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"resolution": 0.0}, "planning.resolution"),
        ({"max_cells": 3}, "planning.max_cells"),
        ({"slope_weight": -1.0}, "planning.slope_weight"),
        ({"slope_limit_deg": 95.0}, "planning.slope_limit_deg"),
        ({"step_limit": -0.1}, "planning.step_limit"),
        ({"roughness_limit": 0.0}, "planning.roughness_limit"),
        ({"inflation_margin": float("nan")}, "planning.inflation_margin"),
        ({"border_margin": -1.0}, "planning.border_margin"),
        ({"slope_margin_deg": -1.0}, "planning.slope_margin_deg"),
    ],
)
def test_bad_config_names_the_key(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        CostMapConfig(**kwargs)


def test_margin_larger_than_the_limit_is_rejected(jackal):
    with pytest.raises(ConfigError, match=r"planning\.slope_margin_deg"):
        build_costmap(flat_world(), jackal, CostMapConfig(slope_limit_deg=10.0, slope_margin_deg=10.0))


def test_mars_yard_hill_top_is_not_reachable(mars_yard, jackal):
    cm = build_costmap(mars_yard, jackal)
    t = mars_yard.terrain
    iy, ix = np.unravel_index(np.argmax(t.heights), t.shape)
    xt, yt = t.cell_xy(ix, iy)
    assert not cm.largest_component_mask[cm.world_to_cell(xt, yt)[::-1]]
    angles = np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False)
    flank = cm.traversable(xt + 2.0 * np.cos(angles), yt + 2.0 * np.sin(angles))
    assert flank.mean() < 0.25  # the steep flanks 2 m from the summit are mostly untraversable
    assert 0.6 < cm.free.mean() < 0.9
    assert cm.largest_component_mask.mean() > 0.6


def test_gentle_hills_are_one_traversable_region(hills_world, jackal):
    cm = build_costmap(hills_world, jackal)
    assert np.all(cm.layers["slope_deg"] < jackal.max_slope_deg)
    assert np.array_equal(cm.free, ~cm.layers["border"])
    assert cm.n_components == 1 and np.all(cm.cost[cm.free] > 1.0 - 1e-12)


def test_components_match_the_search_graph(mars_yard, jackal):
    """Same label <=> a path exists: what lets the sampler promise a reachable goal."""
    from scipy.sparse.csgraph import connected_components

    from diana_lab.planning.paths import _graph

    cm = build_costmap(mars_yard, jackal)
    _, graph_labels = connected_components(_graph(cm, True), directed=False)
    free = cm.free.ravel()
    ours = cm.components.ravel()[free]
    theirs = graph_labels[free]
    # a one-to-one relabelling: every component of ours is exactly one component of the graph
    pairs = np.unique(np.stack([ours, theirs]), axis=1)
    assert len(np.unique(pairs[0])) == len(np.unique(pairs[1])) == pairs.shape[1] == cm.n_components


def test_costmap_pickles_with_its_caches(jackal):
    import pickle

    from diana_lab.planning import plan

    cm = build_costmap(flat_world(obstacles=[box(-1.0, 1.0, -1.0, 1.0, 1.0)]), jackal)
    path = plan(cm, np.array([-5.0, 0.0]), np.array([5.0, 0.0]))
    clone = pickle.loads(pickle.dumps(cm))
    assert np.array_equal(clone.cost, cm.cost) and clone.n_components == cm.n_components
    assert plan(clone, np.array([-5.0, 0.0]), np.array([5.0, 0.0])).length == pytest.approx(path.length)
