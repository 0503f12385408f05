"""The slope shield's detour: when it counts a rover as stalled, what its search takes as a wall, and which
drive it makes round one."""

from __future__ import annotations

import math
import sys
from dataclasses import asdict

import numpy as np
import pytest

from diana_lab.config import ConfigError, to_object
from diana_lab.config.evaluation import ShieldConfig
from diana_lab.core.candidates import candidate_offsets
from diana_lab.shield import ShieldSettings, SlopeShield
from diana_lab.shield.detour import Detour
from tests.shield.test_slope_shield import ground, shield

ROBOT = to_object("robot", "jackal")
RING = candidate_offsets(32, (1.0, 2.0, 3.0))  # the reference policy's 96 candidates, world frame at yaw 0
DETOUR = {"detour_after": 4, "detour_progress": 0.5, "detour_margin": 10.0, "top_k": 96, "hazard_radius": 0.5}


def seen(fn, **overrides) -> SlopeShield:
    """A shield whose map holds ``z = fn(x, y)`` over 16 m round the origin."""
    s = shield(**overrides)
    s.observe(ground(fn, half=8.0), np.zeros(2))
    return s


def wall(x, y):
    """A 0.5 m wall across y = 2 (0.6 m thick) from the far west to x = 3: the way round lies east."""
    return np.where((np.abs(y - 2.0) < 0.3) & (x < 3.0), 0.5, 0.0)


GOAL = np.array([0.0, 4.0])  # behind the wall
NORTH = np.arange(96)[np.argsort(np.hypot(*(RING - GOAL[None]).T))]  # the policy pushes at the wall


def stall(s: SlopeShield, n: int) -> list[int]:
    """``n`` decisions from places 0.1 m apart along x, the goal never nearer: the picks."""
    return [s.choose(NORTH, RING, np.array([0.1 * i, 0.0]), GOAL) for i in range(n)]


@pytest.mark.parametrize(("slope_deg", "drivable"), [(10.0, True), (24.0, True), (30.0, True), (40.0, False)])
def test_a_cell_is_a_wall_only_where_no_heading_passes_the_tilt_check(slope_deg, drivable):
    """Driving diagonally across a 30 deg plane gives 22 deg of pitch and of roll: the shield allows it, so the
    search must not call that ground a wall; at 40 deg every heading fails both."""
    s = seen(lambda x, y: math.tan(math.radians(slope_deg)) * x, **DETOUR)
    m = s.memory
    ix, iy = (int((0.0 - o) / m.cell_size) for o in m.origin)
    free = s.detour.traversable(m, (ix - 2, iy - 2, ix + 3, iy + 3))
    assert free.shape == (5, 5) and bool(free.all()) == drivable and bool(free.any()) == drivable
    some_drive_allowed = any(s.allows(np.zeros(2), o) for o in RING)
    assert some_drive_allowed == drivable


def test_unseen_ground_is_drivable():
    s = seen(lambda x, y: np.where(x > 1.0, 0.9 * (x - 1.0), 0.0), **DETOUR)  # 42 deg beyond x = 1, seen to 8 m
    m = s.memory
    ix, iy = (int((0.0 - o) / m.cell_size) for o in m.origin)
    free = s.detour.traversable(m, (ix + 40, iy, ix + 60, iy + 5))  # x = 8..12 m: never seen
    assert np.isnan(m.height.reshape(m.n, m.n)[iy, ix + 45]) and free.all()
    assert not s.detour.traversable(m, (ix + 10, iy, ix + 20, iy + 5)).any()  # the seen slope is a wall


def test_a_stalled_rover_drives_round_the_wall_and_not_before():
    s = seen(wall, **DETOUR)
    before = stall(s, 4)
    assert s.detours == 0  # 3 decisions without progress: the shield's usual choice
    assert all(RING[k][0] < 1.5 for k in before)  # along the wall, near the goal's bearing
    k = s.choose(NORTH, RING, np.array([0.4, 0.0]), GOAL)  # the 4th decision without progress
    assert s.detours == 1
    assert RING[k][0] > 1.5 and s.allows(np.array([0.4, 0.0]), RING[k])  # east, towards the wall's end
    assert s.vetoes == sum(k != NORTH[0] for k in before)  # a detour is not counted as a veto


def test_the_detour_leads_round_the_end_until_the_rover_gains_again():
    s = seen(wall, **DETOUR)
    stall(s, 4)
    here, picks = np.array([0.4, 0.0]), []
    for _ in range(6):  # drive what the shield picks
        k = s.choose(NORTH, RING, here, GOAL)
        here = here + RING[k]
        picks.append(s.detours)
        if here[1] > 2.5:
            break
    assert here[1] > 2.5, f"the rover did not get past the wall: {here}"  # round the east end
    assert picks[-1] > picks[0]  # the detour drove on
    made = s.detours
    s.choose(NORTH, RING, here, GOAL)  # nearer the goal than ever: progress, the usual choice again
    assert s.detour.since == 0 and s.detours == made


def test_decisions_from_the_same_place_do_not_count():
    s = seen(wall, **DETOUR)
    for _ in range(10):
        s.choose(NORTH, RING, np.zeros(2), GOAL)
    assert s.detour.since == 0 and s.detours == 0


def test_progress_resets_the_count_and_a_reset_forgets_it():
    s = seen(wall, **DETOUR)
    stall(s, 3)
    s.choose(NORTH, RING, np.array([0.0, 0.6]), GOAL)  # 0.6 m nearer than ever
    assert s.detour.since == 0
    stall(s, 5)
    assert s.detour.since >= 4
    s.reset()
    assert (s.detour.since, s.detour.best) == (0, math.inf)


def test_without_a_goal_or_with_the_rule_off_there_is_no_detour():
    s = seen(wall, **DETOUR)
    for i in range(8):
        s.choose(NORTH, RING, np.array([0.1 * i, 0.0]))  # no goal given
    assert s.detours == 0
    off = seen(wall, **{**DETOUR, "detour_after": 0})
    assert off.detour is None
    stall(off, 8)
    assert off.detours == 0


def test_a_hazard_felt_closes_the_way_and_the_search_finds_the_other():
    s = seen(lambda x, y: np.where((np.abs(y - 2.0) < 0.3) & (np.abs(x) < 5.0), 0.5, 0.0), **DETOUR)
    start, ends = np.zeros(2), RING
    ctg = s.detour.costs_to_go(s.memory, s.hazards, start, GOAL, start + ends)
    east, west = ends[:, 0] > 1.5, ends[:, 0] < -1.5
    assert np.isfinite(ctg[east]).any() and np.isfinite(ctg[west]).any()
    for x in np.arange(5.0, 7.01, 0.2):  # hazards felt across the east gap, wall to map edge
        s.mark_hazard([x, 2.0])
    ctg_after = s.detour.costs_to_go(s.memory, s.hazards, start, GOAL, start + ends)
    assert np.nanmin(ctg_after[east]) > np.nanmin(ctg[east]) + 1.0  # east is now the long way
    assert np.nanmin(ctg_after[west]) == pytest.approx(np.nanmin(ctg[west]))


def test_a_goal_on_steep_ground_is_still_reached():
    s = seen(lambda x, y: np.where(np.hypot(x, y - 4.0) < 0.5, 0.8 * (0.5 - np.hypot(x, y - 4.0)), 0.0), **DETOUR)
    ctg = s.detour.costs_to_go(s.memory, s.hazards, np.zeros(2), GOAL, np.array([[0.0, 3.0], [3.0, 0.0]]))
    assert ctg == pytest.approx([1.0, math.hypot(3.0, 4.0)], abs=0.5)


def test_no_map_or_a_goal_off_it_gives_no_detour():
    s = shield(**DETOUR)
    assert s.detour.costs_to_go(s.memory, s.hazards, np.zeros(2), GOAL, RING) is None  # nothing seen yet
    s.observe(ground(wall, half=8.0), np.zeros(2))
    far = np.array([500.0, 0.0])  # the map covers 64 m around the first pose
    assert s.detour.costs_to_go(s.memory, s.hazards, np.zeros(2), far, RING) is None


def test_a_sidecar_written_before_the_detour_reads_it_as_off():
    node = asdict(ShieldSettings.from_config(ShieldConfig(enabled=True, **DETOUR), ROBOT))
    older = {k: v for k, v in node.items() if not k.startswith("detour_")}
    s = SlopeShield(ShieldSettings.from_dict(older))
    assert s.detour is None and s.cfg.detour_after == 0
    assert SlopeShield(ShieldSettings.from_dict(node)).detour.after == 4


def test_the_detour_needs_numba_and_says_so(monkeypatch):
    monkeypatch.setitem(sys.modules, "diana_lab.core.grid_search", None)  # as on a rover without numba
    with pytest.raises(ValueError, match=r"detour_after > 0.*needs numba"):
        shield(**DETOUR)
    assert shield(top_k=96).detour is None  # the rule off needs nothing


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("detour_after", -1),
        ("detour_after", 1.5),
        ("detour_after", True),
        ("detour_progress", 0.0),
        ("detour_margin", -1.0),
    ],
)
def test_bad_detour_settings_name_their_key(key, value):
    with pytest.raises(ConfigError, match=f"eval.shield.{key}"):
        ShieldConfig(**{key: value})


def test_bad_detour_settings_are_refused_by_the_shield_and_the_planner():
    node = asdict(ShieldSettings.from_config(ShieldConfig(enabled=True, **DETOUR), ROBOT))
    with pytest.raises(ValueError, match=r"shield\.detour_progress: expected"):
        SlopeShield(ShieldSettings.from_dict({**node, "detour_progress": 0.0}))
    with pytest.raises(ValueError, match="after >= 1"):
        Detour(0, 0.5, 10.0, 25.0, 0.5)


def test_a_gap_narrower_than_the_rover_is_no_way_through():
    """A 0.2 m slot in the wall (one map cell) would let a search on single cells through; the rover's track
    is 0.38 m, so the search's cells are 2 x 2 map cells, and the way leads round the wall's end."""
    slot = np.array([0.1, 2.0])

    def slotted(x, y):
        return np.where(np.abs(x - slot[0]) < 0.1, 0.0, wall(x, y))

    s = seen(slotted, **DETOUR)
    assert s.detour.pool == 2
    m = s.memory
    ix, iy = (int((v - o) / m.cell_size) for v, o in zip(slot, m.origin))
    assert s.detour.traversable(m, (ix, iy - 3, ix + 1, iy + 4)).all()  # the slot's own map cells are drivable
    ends = np.array([[0.1, 1.0], [3.5, 1.0]])  # before the slot; before the wall's end
    ctg = s.detour.costs_to_go(s.memory, s.hazards, np.zeros(2), GOAL, ends)
    assert ctg[0] > 3.0 + 2.0  # not 3 m straight through the slot: round the end
    assert ctg[0] > ctg[1]


def test_with_the_relief_check_its_hazards_are_walls_for_the_search():
    """A bank of 23.5 deg up to a terrace, under the tilt check's limit: a wall only with the relief check on."""

    def kerb(x, y):
        return math.tan(math.radians(23.5)) * np.clip(y - 1.4, 0.0, 1.2)

    for relief, walled in ((False, False), (True, True)):
        s = seen(kerb, relief=relief, **DETOUR)
        m = s.memory
        ix, iy = (int((v - o) / m.cell_size) for v, o in zip((0.0, 2.0), m.origin))
        free = s.detour.traversable(m, (ix - 2, iy - 2, ix + 3, iy + 3))
        assert bool((~free).any()) == walled
