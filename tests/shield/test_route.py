"""The slope shield's route rule and its search's slope cost: which drives it opens to the policy, which of them
it drives, and what the search charges for slope."""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
import pytest

from diana_lab.config import ConfigError
from diana_lab.config.evaluation import ShieldConfig
from diana_lab.shield import ShieldSettings, SlopeShield
from diana_lab.shield.detour import SlopeCost
from tests.shield.test_detour import GOAL, NORTH, RING, ROBOT, seen, wall
from tests.shield.test_slope_shield import shield

ROUTE = {"route": True, "route_tolerance": 1.0, "top_k": 96, "hazard_radius": 0.5}


def scores(s: SlopeShield, start: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each candidate's drive length plus cost to go, and whether the shield allows it (independently of the
    rule: :meth:`SlopeShield.allows`)."""
    ctg = s.detour.costs_to_go(s.memory, s.hazards, start, goal, start + RING)
    allowed = np.array([s.allows(start, o) for o in RING])
    return np.hypot(RING[:, 0], RING[:, 1]) + ctg, allowed


def test_behind_a_wall_it_drives_the_policys_most_probable_drive_on_a_way_round():
    """The policy pushes at a wall (its candidates nearest the goal first); the rule opens only the drives within
    1 m of the least length + cost to go (the way round the wall's east end), and drives the policy's first of
    them at the very first decision (no stall needed, unlike the detour)."""
    s = seen(wall, **ROUTE)
    start = np.zeros(2)
    score, allowed = scores(s, start, GOAL)
    best = score[allowed].min()
    on_route = allowed & (score <= best + 1.0)
    expected = next(int(k) for k in NORTH if on_route[k])
    k = s.choose(NORTH, RING, start, GOAL)
    assert k == expected and k != NORTH[0]
    assert RING[k][1] < 1.7 and RING[k][0] >= 0.0  # short of the wall, not west of the start
    assert s.routes == 1 and s.vetoes == 0 and s.detours == 0  # not a veto, not a detour
    assert not on_route[NORTH[0]]  # the policy's own choice leads at the wall


def test_on_open_ground_the_policys_choice_is_on_the_way_and_driven_unchanged():
    s = seen(lambda x, y: 0.0 * x, **ROUTE)
    goal = np.array([0.0, 6.0])
    straight = int(np.argmin(np.hypot(*(RING - np.array([0.0, 3.0])[None]).T)))  # 3 m towards the goal
    ranking = [straight, *(k for k in range(96) if k != straight)]
    assert s.choose(ranking, RING, np.zeros(2), goal) == straight
    assert s.routes == 0 and s.vetoes == 0


def test_a_tolerance_wider_than_every_way_keeps_out_only_the_drives_with_no_way():
    """With every way within the tolerance, the rule drives the policy's first allowed drive that has a way to the
    goal: on open ground what the shield without it drives; at the wall, not a drive ending in the search's walls
    (which are a track wide round the wall's own cells)."""
    rng = np.random.default_rng(0)
    gentle = lambda x, y: 0.1 * np.sin(x) * np.cos(0.5 * y)  # noqa: E731
    wide = seen(gentle, **{**ROUTE, "route_tolerance": 1000.0})
    plain = seen(gentle, top_k=96, hazard_radius=0.5)
    for _ in range(5):
        ranking = rng.permutation(96)
        start, goal = rng.uniform(-2.0, 2.0, 2), rng.uniform(-6.0, 6.0, 2)
        assert wide.choose(ranking, RING, start, goal) == plain.choose(ranking, RING, start, goal)
    assert wide.routes == 0
    at_wall = seen(wall, **{**ROUTE, "route_tolerance": 1000.0})
    score, allowed = scores(at_wall, np.zeros(2), GOAL)
    first_allowed = next(int(k) for k in NORTH if allowed[k])
    expected = next(int(k) for k in NORTH if allowed[k] and np.isfinite(score[k]))
    assert not np.isfinite(score[first_allowed])  # it ends in the search's wall
    assert at_wall.choose(NORTH, RING, np.zeros(2), GOAL) == expected != first_allowed


def test_a_drive_ending_where_the_rover_stood_gives_way_to_another_on_the_route():
    s = seen(wall, **{**ROUTE, "revisit_radius": 1.0})
    start = np.zeros(2)
    first = s.choose(NORTH, RING, start, GOAL)
    s.choose(NORTH, RING, start + RING[first], GOAL)  # a decision where that drive ends: a place stood on
    second = s.choose(NORTH, RING, start, GOAL)
    score, allowed = scores(s, start, GOAL)
    assert second != first and np.hypot(*(RING[second] - RING[first])) >= 1.0
    assert allowed[second] and score[second] <= score[allowed].min() + 1.0  # still on a way round


def test_without_a_goal_or_a_map_the_rule_stands_aside():
    s, plain = seen(wall, **ROUTE), seen(wall, top_k=96, hazard_radius=0.5)
    assert s.choose(NORTH, RING, np.zeros(2)) == plain.choose(NORTH, RING, np.zeros(2))  # no goal: as without it
    assert s.routes == 0
    blind = shield(**ROUTE)  # nothing seen yet: no search, and unseen ground passes every check
    assert blind.choose(NORTH, RING, np.zeros(2), GOAL) == NORTH[0] and blind.routes == 0


def test_without_the_detour_the_rule_searches_but_never_counts_a_stall():
    s = seen(wall, **ROUTE)
    assert s.cfg.detour_after == 0 and s.detour is not None
    for i in range(8):
        s.choose(NORTH, RING, np.array([0.1 * i, 0.0]), GOAL)
    assert s.detours == 0 and s.detour.since == 0


@pytest.mark.parametrize("slope_deg", [18.5, 20.0])
def test_the_search_charges_slope_over_its_start_as_the_oracles_cost_map_charges_pitch(slope_deg):
    """On a plane of ``slope_deg`` each metre of the way costs ``1 + weight * e**2``, ``e`` the slope's excess
    over 15 deg as a share of the 7 deg up to 22; without the cost, a metre. (Two ends 4 m apart along the fall
    line: the difference of their costs to go leaves out the goal's own cells, which cost their length.)"""
    rise = math.tan(math.radians(slope_deg))
    goal, ends = np.array([0.0, 0.0]), np.array([[3.0, 0.0], [7.0, 0.0]])
    per_4m = {}
    for weight in (0.0, 10.0):
        s = seen(lambda x, y: rise * x, **{**ROUTE, "slope_cost_weight": weight})
        ctg = s.detour.costs_to_go(s.memory, s.hazards, ends[0], goal, ends)
        per_4m[weight] = float(ctg[1] - ctg[0])
    factor = 1.0 + 10.0 * ((slope_deg - 15.0) / 7.0) ** 2
    assert per_4m[0.0] == pytest.approx(4.0, abs=0.3)
    assert per_4m[10.0] / per_4m[0.0] == pytest.approx(factor, rel=0.05)


def test_the_slope_cost_leads_the_way_round_a_hill_the_plain_search_crosses():
    """A 19 deg hill between the rover and the goal, flat ground round it: the plain search goes over, the
    charged one round."""

    def hill(x, y):
        return np.clip(1.2 - math.tan(math.radians(19.0)) * np.hypot(x, y - 3.0), 0.0, None)

    start, goal = np.array([0.0, -1.0]), np.array([0.0, 7.0])
    over, round_ = np.array([[0.0, 2.0]]), np.array([[4.5, 3.0]])  # onto the hill; beside it
    for weight, hill_first in ((0.0, True), (10.0, False)):
        s = seen(hill, **{**ROUTE, "slope_cost_weight": weight})
        ctg = s.detour.costs_to_go(s.memory, s.hazards, start, goal, np.concatenate([over, round_]))
        via_over = 3.0 + ctg[0]
        via_round = math.hypot(4.5, 4.0) + ctg[1]
        assert (via_over < via_round) == hill_first


def test_unseen_ground_costs_its_length():
    assert SlopeCost(10.0).factor(np.array([np.nan, 0.0, 15.0, 22.0, 40.0])) == pytest.approx([1, 1, 1, 11, 11])


def test_a_sidecar_written_before_the_rule_reads_it_as_off():
    node = asdict(ShieldSettings.from_config(ShieldConfig(enabled=True, **ROUTE, slope_cost_weight=10.0), ROBOT))
    older = {k: v for k, v in node.items() if not k.startswith(("route", "slope_cost"))}
    s = SlopeShield(ShieldSettings.from_dict(older))
    assert not s.cfg.route and s.detour is None
    new = SlopeShield(ShieldSettings.from_dict(node))
    assert new.cfg.route and new.detour.slope_cost == SlopeCost(10.0, 15.0, 22.0)


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        ({"route_tolerance": -0.5}, "route_tolerance"),
        ({"route": "yes"}, "route"),
        ({"slope_cost_weight": -1.0}, "slope_cost_weight"),
        ({"slope_cost_from_deg": 0.0}, "slope_cost_from_deg"),
        ({"slope_cost_from_deg": 22.0, "slope_cost_to_deg": 20.0}, "slope_cost_to_deg"),
    ],
)
def test_bad_route_settings_name_their_key(overrides, key):
    with pytest.raises(ConfigError, match=f"eval.shield.{key}"):
        ShieldConfig(**overrides)


def test_bad_route_settings_are_refused_by_the_shield_too():
    node = asdict(ShieldSettings.from_config(ShieldConfig(enabled=True, **ROUTE), ROBOT))
    with pytest.raises(ValueError, match="route_tolerance"):
        SlopeShield(ShieldSettings.from_dict({**node, "route_tolerance": -1.0}))
    with pytest.raises(ValueError, match=r"shield\.slope_cost_to_deg: expected more than"):
        SlopeShield(ShieldSettings.from_dict({**node, "slope_cost_weight": 1.0, "slope_cost_to_deg": 10.0}))
