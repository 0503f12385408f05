"""The site map: what the shield's search assumes of ground its own map has not seen."""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
import pytest

from diana_lab.config import ConfigError
from diana_lab.config.evaluation import ShieldConfig
from diana_lab.shield import ShieldSettings, SiteMap
from diana_lab.sim.terrain import Terrain
from tests.shield.test_detour import DETOUR, RING, ROBOT, seen
from tests.shield.test_slope_shield import ground, shield


def site_of(fn, half: float = 20.0, cell: float = 0.2) -> SiteMap:
    """The site map of ``z = fn(x, y)`` over ``half`` m round the origin: each cell's height at its centre."""
    centres = np.arange(-half, half, cell) + cell / 2
    x, y = np.meshgrid(centres, centres)
    return SiteMap(fn(x, y), (-half, -half), cell)


def far_wall(x, y, end: float = 3.0):
    """A 0.5 m wall across y = 6 (0.6 m thick) from the far west to x = ``end``, beyond what the rover has seen."""
    return np.where((np.abs(y - 6.0) < 0.3) & (x < end), 0.5, 0.0)


def flat(x, y):
    return np.zeros_like(x)


GOAL = np.array([0.0, 9.0])  # behind the far wall


def near_only(**overrides):
    """A shield that has seen flat ground to 2 m round the origin and nothing of the wall."""
    s = shield(**{**DETOUR, **overrides})
    s.observe(ground(flat, half=2.0), np.zeros(2))
    return s


def north_cost(s) -> float:
    """The search's cost to go from 1 m north of the origin to the goal."""
    return float(s.detour.costs_to_go(s.memory, s.hazards, np.zeros(2), GOAL, np.array([[0.0, 1.0]]))[0])


@pytest.mark.parametrize("slope_deg", [5.0, 20.0, 35.0])
def test_a_plane_reads_as_its_slope_and_off_the_map_as_nothing(slope_deg):
    rise = math.tan(math.radians(slope_deg))
    site = site_of(lambda x, y: rise * (0.6 * x - 0.8 * y))
    gx, gy = site.gradient_at(np.array([0.0, 3.3, 19.9]), np.array([0.0, -7.1, 19.9]))
    assert gx == pytest.approx(0.6 * rise) and gy == pytest.approx(-0.8 * rise)
    gx, gy = site.gradient_at(np.array([-20.1, 20.0, 0.0]), np.array([0.0, 0.0, 25.0]))
    assert np.isnan(gx).all() and np.isnan(gy).all()


def test_from_terrain_averages_the_ground_over_each_square():
    """A simulated world's map: its cells average the terrain over their square (a bump narrower than a cell
    lowers it), and a plane keeps its slope."""
    n = 101  # 0.1 m samples over 10 m
    g = np.linspace(-5.0, 5.0, n)
    x, y = np.meshgrid(g, g)
    plane = Terrain(0.3 * x + 0.1 * y, 10.0, 10.0)
    site = SiteMap.from_terrain(plane, 0.5)
    assert site.heights.shape == (20, 20) and tuple(site.origin) == (-5.0, -5.0)
    assert site.heights[0, 0] == pytest.approx(0.3 * -4.75 + 0.1 * -4.75)  # the square's centre on a plane
    gx, gy = site.gradient_at(np.array([1.2]), np.array([-2.2]))
    assert (gx[0], gy[0]) == pytest.approx((0.3, 0.1))
    spike = Terrain(np.where((np.abs(x) < 0.05) & (np.abs(y) < 0.05), 1.0, 0.0), 10.0, 10.0)
    coarse = SiteMap.from_terrain(spike, 1.0, samples=8)
    assert 0 < coarse.heights.max() < 0.2  # a one-sample spike averaged into a 1 m square


@pytest.mark.parametrize(
    ("heights", "origin", "cell", "named"),
    [
        (np.zeros(5), (0, 0), 0.2, "heights"),
        (np.zeros((1, 5)), (0, 0), 0.2, "heights"),
        (np.array([[0.0, np.nan], [0.0, 0.0]]), (0, 0), 0.2, "heights"),
        (np.zeros((3, 3)), (0, 0, 0), 0.2, "origin"),
        (np.zeros((3, 3)), (0, np.inf), 0.2, "origin"),
        (np.zeros((3, 3)), (0, 0), 0.0, "cell"),
        (np.zeros((3, 3)), (0, 0), -1.0, "cell"),
        (np.zeros((3, 3)), (0, 0), float("nan"), "cell"),
        (np.zeros((3, 3)), (0, 0), "0.2", "cell"),
        (np.zeros((3, 3)), (0, 0), True, "cell"),
        (np.zeros((3, 3), dtype=complex), (0, 0), 0.2, "complex"),
        ([["a", "b"], ["c", "d"]], (0, 0), 0.2, "numeric"),
    ],
)
def test_bad_site_maps_are_refused_naming_what(heights, origin, cell, named):
    with pytest.raises(ValueError, match=named):
        SiteMap(heights, origin, cell)


def test_a_cell_too_coarse_or_far_too_fine_for_the_terrain_is_refused():
    terrain = Terrain(np.zeros((11, 11)), 10.0, 10.0)
    with pytest.raises(ValueError, match="cell 8"):
        SiteMap.from_terrain(terrain, 8.0)
    with pytest.raises(ValueError, match=r"cell 0\.001 m makes 10000 x 10000 squares"):  # 100 M: refused, not built
        SiteMap.from_terrain(terrain, 0.001)


@pytest.mark.parametrize(("cell", "samples"), [("0.2", 4), (True, 4), (None, 4), (0.5, 0), (0.5, 2.0)])
def test_from_terrain_refuses_a_cell_or_samples_that_are_not_numbers_naming_them(cell, samples):
    with pytest.raises(ValueError, match=r"cell|samples"):
        SiteMap.from_terrain(Terrain(np.zeros((11, 11)), 10.0, 10.0), cell, samples)


def test_built_in_blocks_it_is_the_same_map(monkeypatch):
    """A large world is sampled a block of rows at a time (memory); the blocks join into the same map."""
    import diana_lab.shield.site_map as module

    g = np.linspace(-5.0, 5.0, 51)
    x, y = np.meshgrid(g, g)
    terrain = Terrain(np.sin(x) * np.cos(0.7 * y), 10.0, 10.0)
    whole = SiteMap.from_terrain(terrain, 0.3)
    monkeypatch.setattr(module, "_BLOCK_SAMPLES", 500)  # a few rows of squares a block
    assert np.array_equal(SiteMap.from_terrain(terrain, 0.3).heights, whole.heights)


def test_unseen_ground_is_judged_by_the_site_map():
    """Without a site map the search takes the unseen wall's ground as free and heads straight for the goal;
    with one it knows the wall and its cost to go is the way round the east end."""
    blind = near_only()
    assert north_cost(blind) == pytest.approx(8.0, abs=0.3)  # straight through, 8 m
    mapped = near_only()
    mapped.use_site_map(site_of(far_wall))
    round_east = north_cost(mapped)
    assert round_east > 10.0  # to x > 3 and back: at least 2 x 3 m sideways on a 5 m climb north
    closed = near_only()
    closed.use_site_map(site_of(lambda x, y: np.where(np.abs(y - 6.0) < 0.3, 0.5, 0.0)))  # no end in the map
    assert np.isinf(north_cost(closed))


def test_the_route_rule_with_a_site_map_sets_off_towards_the_way_round():
    """At the first decision, before any stall, the route rule opens only the drives towards the wall's end (6 m
    east: north would cost more than the rule's 1 m tolerance)."""
    policy_north = np.arange(96)[np.argsort(np.hypot(*(RING - GOAL[None]).T))]
    picks = {}
    for name, site in (("blind", None), ("mapped", site_of(lambda x, y: far_wall(x, y, end=6.0)))):
        s = near_only(route=True)
        s.use_site_map(site)
        picks[name] = RING[s.choose(policy_north, RING, np.zeros(2), GOAL)]
    assert abs(picks["blind"][0]) < 0.5  # straight north
    assert picks["mapped"][0] > 0.5  # east, towards the wall's end


def test_ground_the_shield_has_seen_wins_over_the_site_map():
    """The site map is older than what the rover measured today: a wall it shows where the rover saw flat ground
    is no wall, and the slope the rover saw is judged by its own map."""
    s = seen(flat, **DETOUR)  # flat ground seen 8 m round the origin
    s.use_site_map(site_of(lambda x, y: np.where(np.abs(y - 2.0) < 0.3, 0.5, 0.0)))  # a wall at y = 2, long gone
    m = s.memory
    ix, iy = (int((0.0 - o) / m.cell_size) for o in m.origin)
    assert s.detour.traversable(m, (ix - 5, iy, ix + 5, iy + 20)).all()
    assert north_cost(s) == pytest.approx(8.0, abs=0.3)


def test_the_site_map_outlives_reset_and_none_removes_it():
    s = near_only()
    site = site_of(far_wall)
    s.use_site_map(site)
    s.reset()
    assert s.detour.site_map is site  # the site's, not the traverse's
    s.observe(ground(flat, half=2.0), np.zeros(2))
    assert north_cost(s) > 10.0
    s.use_site_map(None)
    assert north_cost(s) == pytest.approx(8.0, abs=0.3)


def test_a_shield_without_a_search_refuses_a_site_map():
    with pytest.raises(ValueError, match="no search"):
        shield().use_site_map(site_of(flat))


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"site_map_cell": -0.2, "detour_after": 2}, "eval.shield.site_map_cell"),
        ({"site_map_cell": 0.2}, "eval.shield.site_map_cell=0.2: .*detour_after"),
    ],
)
def test_bad_site_map_settings_name_their_key(overrides, match):
    with pytest.raises(ConfigError, match=match):
        ShieldConfig(enabled=True, **overrides)


def test_the_setting_reaches_the_sidecar_and_an_older_sidecar_has_none():
    settings = ShieldSettings.from_config(ShieldConfig(enabled=True, route=True, site_map_cell=0.4), ROBOT)
    node = asdict(settings)
    assert node["site_map_cell"] == 0.4
    del node["site_map_cell"]
    assert ShieldSettings.from_dict(node).site_map_cell == 0.0
    with pytest.raises(ValueError, match="site_map_cell"):
        ShieldSettings.from_dict({**node, "site_map_cell": 0.2, "route": False, "detour_after": 0})
