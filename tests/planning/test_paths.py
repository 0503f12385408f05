"""Planning: straight lines on open ground, detours that match geometry, no paths across components."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from diana_lab.planning import CostMapConfig, build_costmap, plan, shortest_path_length, simplify
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import World
from tests.planning.helpers import box, dense, flat_world

# the worst grid detour: 45-degree moves only, heading 22.5 degrees off the grid axes
GRID_OVERESTIMATE = np.sqrt(4.0 - 2.0 * np.sqrt(2.0))


@pytest.fixture(scope="module")
def open_ground(jackal):
    return build_costmap(flat_world(), jackal)


def test_open_ground_paths_are_straight_lines(open_ground, rng):
    for _ in range(20):
        start, goal = rng.uniform(-9.0, 9.0, size=(2, 2))
        straight = float(np.hypot(*(goal - start)))
        path = plan(open_ground, start, goal)
        assert path is not None
        assert np.allclose(path.points[0], start) and np.allclose(path.points[-1], goal)
        assert path.length == pytest.approx(straight, rel=1e-9, abs=1e-9)
        assert shortest_path_length(open_ground, start, goal) == pytest.approx(straight, abs=1e-9)
        raw = plan(open_ground, start, goal, smooth=False)
        # a grid path: never shorter than the line and at most ~8.2 % longer (plus the end cells' offsets)
        slack = 2.0 * np.sqrt(0.5) * open_ground.resolution
        assert straight - 1e-9 <= raw.length <= GRID_OVERESTIMATE * straight + slack
        assert raw.cost == pytest.approx(path.cost)  # the cost is the search's, smoothing keeps it


def test_grid_overestimate_bound_is_reached_at_22_5_degrees(open_ground):
    heading = np.radians(22.5)
    start = np.array([-8.0, -3.0])
    goal = start + 16.0 * np.array([np.cos(heading), np.sin(heading)])
    raw = plan(open_ground, start, goal, smooth=False)
    assert raw.length / 16.0 == pytest.approx(GRID_OVERESTIMATE, abs=0.01)
    assert GRID_OVERESTIMATE < 1.083


def test_wall_forces_a_detour_of_the_right_length(jackal):
    world = flat_world(obstacles=[box(-0.2, 0.2, -11.0, 6.0, 1.0)])  # a wall open only at its north end
    cm = build_costmap(world, jackal)
    start, goal = np.array([-5.0, 0.0]), np.array([5.0, 0.0])
    path = plan(cm, start, goal, weighted=False)
    assert path is not None and path.points[:, 1].max() > 6.0
    # taut string over the wall's end inflated by the band radius (robot radius, half a cell, half a raster
    # sample): the hull of {start, goal, inflated end} minus its bottom edge start -> goal
    radius = jackal.radius + 0.5 * cm.resolution + 0.5 * world.obstacle_resolution
    angles = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    circle = radius * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    end = np.vstack([circle + np.array([-0.2, 6.0]), circle + np.array([0.2, 6.0])])
    expected = ConvexHull(np.vstack([end, start, goal])).area - 10.0  # .area is the perimeter in 2-D
    assert path.length == pytest.approx(expected, rel=0.02)
    assert shortest_path_length(cm, start, goal) == pytest.approx(path.length)
    # the robot centre keeps (very nearly) the footprint radius from the wall all along the path
    p = dense(path.points)
    gap = np.hypot(np.maximum(np.abs(p[:, 0]) - 0.2, 0.0), np.maximum(p[:, 1] - 6.0, 0.0))
    assert gap.min() >= jackal.radius - 0.02


def test_no_path_across_components(jackal):
    cm = build_costmap(flat_world(obstacles=[box(-11.0, 11.0, -0.2, 0.2, 1.0)]), jackal)
    start, goal = np.array([0.0, -5.0]), np.array([3.0, 5.0])
    assert cm.component_at(*start) != cm.component_at(*goal)
    assert plan(cm, start, goal) is None
    assert shortest_path_length(cm, start, goal) == float("inf")
    assert plan(cm, start, np.array([3.0, -4.0])) is not None


def test_untraversable_or_outside_endpoints(jackal):
    world = flat_world(obstacles=[box(-0.25, 0.25, -0.25, 0.25, 0.5)])
    cm = build_costmap(world, jackal)
    goal = np.array([5.0, 5.0])
    assert plan(cm, np.array([0.45, 0.0]), goal) is None  # inside the inflation band
    snapped = plan(cm, np.array([0.45, 0.0]), goal, snap=0.5)
    assert snapped is not None and np.allclose(snapped.points[0], [0.45, 0.0])
    assert plan(cm, np.array([30.0, 0.0]), goal, snap=100.0) is None


def test_weighted_paths_avoid_costly_ground(jackal):
    x = -10.0 + 0.2 * np.arange(101)
    mound = 1.2 * np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / (2 * 2.0**2))  # gentle: < 20 degrees
    cm = build_costmap(World("mound", Terrain(mound, 20.0, 20.0)), jackal, CostMapConfig(slope_weight=5.0))
    assert np.all(np.isfinite(cm.cost[40:61, 40:61]))  # the mound is traversable ...
    start, goal = np.array([-7.0, 0.0]), np.array([7.0, 0.0])
    weighted, uniform = plan(cm, start, goal), plan(cm, start, goal, weighted=False)
    assert uniform.length == pytest.approx(14.0, abs=1e-6)  # ... so the shortest path crosses it
    assert shortest_path_length(cm, start, goal, weighted=True) == pytest.approx(weighted.length)
    assert weighted.length > 14.5  # but the least-cost path goes round it
    assert np.abs(dense(weighted.points)[:, 1]).max() > 2.0


def test_simplify_spacing_and_goal(open_ground):
    path = plan(open_ground, np.array([-8.0, -8.0]), np.array([7.0, 6.5]))
    for max_segment in (0.5, 2.0, 100.0):
        wps = simplify(path, max_segment)
        steps = np.hypot(*np.diff(np.vstack([path.points[0], wps]), axis=0).T)
        assert np.all(steps <= max_segment + 1e-9)
        assert np.allclose(wps[-1], path.points[-1])
        assert steps.sum() == pytest.approx(path.length)
    raw = plan(open_ground, np.array([-8.0, 0.0]), np.array([8.0, 0.0]), smooth=False)
    assert len(raw.points) > 50 and len(simplify(raw, 100.0)) == 1  # collinear grid points collapse
    with pytest.raises(ValueError, match="max_segment"):
        simplify(path, 0.0)


def test_mars_yard_plan_respects_slope_limit(mars_yard, jackal, rng):
    cm = build_costmap(mars_yard, jackal)
    main = cm.largest_component_mask & (cm.layers["slope_deg"] < 5.0)
    iy, ix = np.nonzero(main)
    for _ in range(5):
        a, b = rng.choice(len(iy), size=2, replace=False)
        start = np.array(cm.cell_to_world(ix[a], iy[a]))
        goal = np.array(cm.cell_to_world(ix[b], iy[b]))
        path = plan(cm, start, goal)
        assert path is not None
        p = dense(path.points, 0.05)
        assert np.all(cm.traversable(p[:, 0], p[:, 1]))
        pix, piy = cm.world_to_cell(p[:, 0], p[:, 1])
        assert cm.layers["slope_deg"][piy, pix].max() <= jackal.max_slope_deg
        # independently of the footprint plane fit: the terrain's own facets along the path are gentle
        facet_deg = np.degrees(np.arccos(mars_yard.terrain.normal(p[:, 0], p[:, 1])[:, 2]))
        assert np.percentile(facet_deg, 95) < jackal.max_slope_deg
        spl = shortest_path_length(cm, start, goal)
        assert np.hypot(*(goal - start)) - 1e-9 <= spl <= path.length * 1.05
    # the summit of the hill cannot be reached from the flat ground
    t = mars_yard.terrain
    jy, jx = np.unravel_index(np.argmax(t.heights), t.shape)
    assert plan(cm, start, np.array(t.cell_xy(jx, jy))) is None


# ------------------------------------------------------------------------------ next_waypoint (the DAgger expert)


def test_next_waypoint_on_open_ground_heads_straight_for_the_goal(open_ground, rng):
    from diana_lab.planning import next_waypoint

    for _ in range(20):
        start, goal = rng.uniform(-9.0, 9.0, size=(2, 2))
        wp = next_waypoint(open_ground, start, goal, reach=3.0)
        d = float(np.hypot(*(goal - start)))
        if d <= 3.0:
            assert np.allclose(wp, goal)
        else:
            assert np.hypot(*(wp - start)) == pytest.approx(3.0)
            assert np.allclose(wp, start + (goal - start) * 3.0 / d)


def test_next_waypoint_goes_round_a_wall_and_never_through_it(jackal):
    from diana_lab.planning import next_waypoint

    world = flat_world(obstacles=[box(-0.2, 0.2, -11.0, 6.0, 1.0)])  # open only at its north end
    cm = build_costmap(world, jackal)
    start, goal = np.array([-3.0, 0.0]), np.array([3.0, 0.0])
    xy, steps = start.copy(), 0
    while np.hypot(*(goal - xy)) > 1e-6 and steps < 20:
        wp = next_waypoint(cm, xy, goal, reach=3.0)
        assert wp is not None and np.hypot(*(wp - xy)) <= 3.0 + 1e-9
        seg = np.linspace(xy, wp, 50)
        assert np.all(np.isfinite(cm.cost_at(seg[:, 0], seg[:, 1])))  # never enters the wall's band
        xy, steps = wp, steps + 1
    assert np.allclose(xy, goal)
    assert 6 <= steps <= 10  # round the north end (about 17 m at 3 m a step), not a wander


def test_next_waypoint_is_none_without_a_path(jackal):
    from diana_lab.planning import next_waypoint

    world = flat_world(obstacles=[box(-0.2, 0.2, -11.0, 11.0, 1.0)])  # a wall across the whole map
    cm = build_costmap(world, jackal)
    assert next_waypoint(cm, np.array([-3.0, 0.0]), np.array([3.0, 0.0]), reach=3.0) is None
    with pytest.raises(ValueError, match="reach"):
        next_waypoint(cm, np.array([-3.0, 0.0]), np.array([-5.0, 0.0]), reach=0.0)


def test_next_waypoint_among_candidates_picks_one_of_them_and_goes_round_the_wall(jackal):
    # a discrete action space's expert: every waypoint is one of the candidates it was offered
    from diana_lab.envs.action_spaces import candidate_offsets
    from diana_lab.planning import next_waypoint

    world = flat_world(obstacles=[box(-0.2, 0.2, -11.0, 6.0, 1.0)])  # open only at its north end
    cm = build_costmap(world, jackal)
    table = candidate_offsets(32, [1.0, 2.0, 3.0])
    start, goal = np.array([-3.0, 0.0]), np.array([3.0, 0.0])
    xy, steps = start.copy(), 0
    while np.hypot(*(goal - xy)) > 0.5 and steps < 20:
        choices = xy + table
        wp = next_waypoint(cm, xy, goal, reach=3.0, candidates=choices)
        assert wp is not None and np.min(np.hypot(*(choices - wp).T)) == 0.0  # exactly a candidate
        seg = np.linspace(xy, wp, 50)
        assert np.all(np.isfinite(cm.cost_at(seg[:, 0], seg[:, 1])))  # never enters the wall's band
        xy, steps = wp, steps + 1
    assert np.hypot(*(goal - xy)) <= 0.5
    assert 6 <= steps <= 12  # round the north end (about 17 m), not a wander
    # the candidates are all it may choose from: with none traversable there is no answer
    assert next_waypoint(cm, start, goal, reach=3.0, candidates=np.array([[0.0, 0.0]])) is None


def test_a_choice_among_candidates_costs_each_of_them_and_the_chosen_one_least(jackal):
    """``choose_waypoint``'s ``costs`` (the material of soft imitation labels): one per candidate, in their
    order; ``inf`` inside the wall, beyond the map's edge or with no way; the chosen candidate costs the least;
    on open ground a candidate's cost is its drive plus the straight way on, so it grows with the detour."""
    from diana_lab.envs.action_spaces import candidate_offsets
    from diana_lab.planning import choose_waypoint, next_waypoint

    world = flat_world(obstacles=[box(-0.2, 0.2, -11.0, 6.0, 1.0)])
    cm = build_costmap(world, jackal)
    table = candidate_offsets(32, [1.0, 2.0, 3.0])
    start, goal = np.array([-3.0, 0.0]), np.array([3.0, 0.0])
    choices = np.vstack([start + table, [[500.0, 0.0]]])  # and one far off the map
    choice = choose_waypoint(cm, start, goal, reach=3.0, candidates=choices)
    assert choice.costs.shape == (len(choices),)
    assert np.isinf(choice.costs[-1])
    in_wall = np.isinf(cm.cost_at(choices[:, 0], choices[:, 1]))
    assert in_wall.any() and np.all(np.isinf(choice.costs[in_wall]))
    chosen = int(np.argmin(np.hypot(*(choices - choice.waypoint).T)))
    assert choice.costs[chosen] == np.min(choice.costs)
    np.testing.assert_array_equal(next_waypoint(cm, start, goal, reach=3.0, candidates=choices), choice.waypoint)
    assert choose_waypoint(cm, start, goal, reach=3.0).costs is None  # no candidates given: no costs

    open_cm = build_costmap(flat_world(), jackal)
    start, far_goal = np.array([-8.0, 0.0]), np.array([8.0, 0.0])
    costs = choose_waypoint(open_cm, start, far_goal, reach=3.0, candidates=start + table).costs
    bearings = np.arctan2(table[:, 1], table[:, 0])
    three = np.isclose(np.hypot(*table.T), 3.0)
    ahead, aside, behind = (three & np.isclose(np.abs(bearings), b) for b in (0.0, np.pi / 2, np.pi))
    assert costs[ahead][0] < costs[aside].min() < costs[behind][0]
    # a 3 m drive straight ahead and a 1 m one both leave the rest of the straight way: (nearly) a tie
    one_ahead = np.isclose(np.hypot(*table.T), 1.0) & np.isclose(bearings, 0.0)
    assert costs[one_ahead][0] == pytest.approx(costs[ahead][0], rel=0.02)
