"""The bounded grid search answers exactly what scipy's Dijkstra on the planner's graph answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from diana_lab.core.grid_search import cost_to_go
from diana_lab.planning import CostMap, build_costmap, next_waypoint
from diana_lab.planning.paths import _graph


def _random_costmap(rng, shape=(60, 70), lethal=0.25) -> CostMap:
    cost = 1.0 + rng.exponential(2.0, shape)
    cost[rng.random(shape) < lethal] = np.inf  # walls, pockets and diagonal gaps that must not be cut
    return CostMap(cost=cost, resolution=0.2, x_min=-7.0, y_min=-6.0)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("weighted", [True, False])
def test_it_equals_dijkstra_on_the_planners_graph(seed, weighted):
    rng = np.random.default_rng(seed)
    cm = _random_costmap(rng)
    cost = cm.cost if weighted else np.where(cm.free, 1.0, np.inf)
    free = np.flatnonzero(cm.free)
    source = int(rng.choice(free))
    reference = dijkstra(_graph(cm, weighted), directed=True, indices=source)
    focus = int(rng.choice(free))
    fy, fx = divmod(focus, cm.shape[1])
    near = [(fy + dy) * cm.shape[1] + fx + dx for dy in range(-8, 9) for dx in range(-8, 9)]
    near = [c for c in near if 0 <= c < cm.cost.size]
    for targets in (np.array([focus, *near]), rng.choice(cm.cost.size, 40), np.arange(cm.cost.size)):
        found = cost_to_go(cost, cm.resolution, source, targets)
        np.testing.assert_array_equal(found, reference[targets])  # the same floating-point sums
    assert np.isinf(reference).any() and np.isfinite(reference).sum() > 100  # the map has both kinds of cell


def test_an_untraversable_source_reaches_nothing_and_bad_indices_are_refused():
    cm = _random_costmap(np.random.default_rng(0))
    wall = int(np.flatnonzero(~cm.free)[0])
    assert np.isinf(cost_to_go(cm.cost, 0.2, wall, np.arange(10))).all()
    assert cost_to_go(cm.cost, 0.2, int(np.flatnonzero(cm.free)[0]), np.zeros(0, np.int64)).shape == (0,)
    with pytest.raises(ValueError, match="cell indices"):
        cost_to_go(cm.cost, 0.2, cm.cost.size, np.arange(3))
    with pytest.raises(ValueError, match="2-D"):
        cost_to_go(cm.cost.ravel(), 0.2, 0, np.arange(3))


def test_next_waypoint_is_the_same_with_a_bounded_search(mars_yard, jackal, rng):
    from diana_lab.envs.action_spaces import candidate_offsets

    cm = build_costmap(mars_yard, jackal)
    table = candidate_offsets(32, [1.0, 2.0, 3.0])
    free = np.argwhere(cm.free)
    checked = 0
    for _ in range(25):
        (sy, sx), (gy, gx) = free[rng.integers(len(free), size=2)]
        start, goal = np.array(cm.cell_to_world(sx, sy)), np.array(cm.cell_to_world(gx, gy))
        for candidates in (None, start + table):
            full = next_waypoint(cm, start, goal, 3.0, candidates=candidates)
            bounded = next_waypoint(cm, start, goal, 3.0, candidates=candidates, full_search=False)
            assert (full is None) == (bounded is None)
            if full is not None:
                np.testing.assert_array_equal(full, bounded)
                checked += 1
    assert checked > 20
