"""The goal-distance field of the ``path_progress`` reward: the straight line on open ground, the way round a wall,
SPL's shortest path on the Mars yard, and arguments checked early."""

from __future__ import annotations

import numpy as np
import pytest

from diana_lab.planning import GoalDistance, build_costmap, shortest_path_length
from tests.planning.helpers import box, flat_world

GRID_OVERESTIMATE = np.sqrt(4.0 - 2.0 * np.sqrt(2.0))  # 45-degree moves only, 22.5 degrees off the axes


@pytest.fixture(scope="module")
def open_ground(jackal):
    return build_costmap(flat_world(), jackal)


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_on_open_ground_the_field_is_the_straight_line_up_to_the_grid(open_ground, rng, stride):
    gd = GoalDistance(open_ground, stride=stride)
    for _ in range(10):
        goal, start = rng.uniform(-7.0, 7.0, size=(2, 2))
        field = gd.field(goal)
        straight = float(np.hypot(*(start - goal)))
        cell = gd.resolution
        assert gd.at(field, *goal) <= cell  # the goal's own cells start at their distance to it
        assert straight - cell <= gd.at(field, *start) <= GRID_OVERESTIMATE * straight + 2 * cell
        assert np.all(np.isfinite(field))


def test_the_field_goes_round_a_wall_and_the_untraversable_cost_prices_crossing_it(jackal):
    cm = build_costmap(flat_world(obstacles=[box(-0.2, 0.2, -11.0, 6.0, 1.0)]), jackal)  # open at its north end
    start, goal = np.array([-5.0, 0.0]), np.array([5.0, 0.0])
    around = shortest_path_length(cm, start, goal)
    assert around > 15.0  # over the wall's end, not the 10 m straight line
    gd = GoalDistance(cm, stride=1)
    field = gd.field(goal)
    assert gd.at(field, *start) == pytest.approx(around, rel=0.09)  # the grid's 8 % at most
    # crossing the wall costs its width in metres times the cost: cheap enough, and the field cuts through it
    cheap = GoalDistance(cm, stride=1, untraversable_cost=1.0)
    assert cheap.at(cheap.field(goal), *start) == pytest.approx(10.0, abs=0.3)
    # every cell has a distance, inside the wall too: a rover standing there is still priced
    assert np.isfinite(gd.at(field, 0.0, 0.0)) and gd.at(field, 0.0, 0.0) > 5.0


def test_a_field_rebuilt_into_the_same_buffer_depends_only_on_its_goal(open_ground):
    gd = GoalDistance(open_ground, stride=2)
    a = gd.field(np.array([3.0, -2.0])).copy()
    out = gd.field(np.array([-6.0, 5.0]))
    assert gd.field(np.array([3.0, -2.0]), out=out) is out
    np.testing.assert_array_equal(out, a)


def test_on_the_mars_yard_the_field_follows_spls_shortest_path(mars_yard, jackal):
    from diana_lab.planning import shared_costmap

    cm = shared_costmap(mars_yard, jackal)
    rng = np.random.default_rng(5)
    free = np.argwhere(cm.free)
    ratios = {1: [], 2: []}
    gds = {s: GoalDistance(cm, stride=s) for s in ratios}
    for _ in range(12):
        (sy, sx), (gy, gx) = free[rng.integers(len(free), size=2)]
        start, goal = np.array(cm.cell_to_world(sx, sy)), np.array(cm.cell_to_world(gx, gy))
        shortest = shortest_path_length(cm, start, goal)
        if not np.isfinite(shortest) or shortest < 5.0:
            continue
        for s, gd in gds.items():
            ratios[s].append(gd.at(gd.field(goal), *start) / shortest)
    assert len(ratios[1]) >= 5
    # stride 1: the grid's overestimate, or less where crossing a thin hazard is cheaper than going round
    assert 0.95 <= np.median(ratios[1]) <= GRID_OVERESTIMATE
    assert 0.9 <= np.median(ratios[2]) <= 1.15


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"stride": 0}, "stride"), ({"stride": 1.5}, "stride"), ({"untraversable_cost": 0.5}, "untraversable_cost")],
)
def test_bad_arguments_are_named(open_ground, kwargs, name):
    with pytest.raises(ValueError, match=name):
        GoalDistance(open_ground, **kwargs)


def test_the_bucket_queue_gives_dijkstras_distances_exactly(rng):
    """Dial's buckets against scipy's Dijkstra on the same 8-connected graph, over costs from 1 to 10."""
    from scipy.sparse import coo_array
    from scipy.sparse.csgraph import dijkstra

    from diana_lab.planning import CostMap

    ny, nx, res = 23, 31, 0.5
    cost = np.where(rng.random((ny, nx)) < 0.3, np.inf, 1.0)  # untraversable: cost 6 in the field
    cm = CostMap(cost, res, 0.0, 0.0)
    gd = GoalDistance(cm, stride=1, untraversable_cost=6.0)
    goal_cell = (7, 12)  # (iy, ix): the goal on a cell centre, which starts at 0
    field = gd.field(np.array([goal_cell[1] * res, goal_cell[0] * res]))
    c = np.where(np.isfinite(cost), 1.0, 6.0).ravel()
    src, dst, weight = [], [], []
    for iy in range(ny):
        for ix in range(nx):
            for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
                vy, vx = iy + dy, ix + dx
                if 0 <= vy < ny and 0 <= vx < nx:
                    a, b = iy * nx + ix, vy * nx + vx
                    src.append(a), dst.append(b), weight.append(0.5 * res * np.hypot(dy, dx) * (c[a] + c[b]))
    graph = coo_array((weight, (src, dst)), shape=(ny * nx, ny * nx)).tocsr()
    want = dijkstra(graph, indices=goal_cell[0] * nx + goal_cell[1]).reshape(ny, nx)
    np.testing.assert_allclose(field, want, rtol=1e-12, atol=1e-12)
