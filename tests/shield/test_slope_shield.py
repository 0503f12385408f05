"""The slope shield: what it reads off its own map, which candidate it lets through, and its config checks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from diana_lab.config import ConfigError, to_object
from diana_lab.config.evaluation import ShieldConfig
from diana_lab.shield import ShieldSettings, SlopeShield
from diana_lab.shield.relief import relief_hazards

ROBOT = to_object("robot", "jackal")  # wheelbase 0.262 m, track 0.376 m


def shield(**overrides) -> SlopeShield:
    return SlopeShield(ShieldSettings.from_config(ShieldConfig(enabled=True, **overrides), ROBOT))


def ground(fn, half: float = 6.0, step: float = 0.05) -> np.ndarray:
    """Dense world points ``z = fn(x, y)`` over a square around the origin, off the 0.2 m cells' edges (a
    point on an edge may fall in either cell, and the map keeps each cell's highest point)."""
    g = np.arange(-half, half + 1e-9, step) + step / 2
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel(), fn(x, y).ravel()])


def seen(fn, **overrides) -> SlopeShield:
    s = shield(**overrides)
    s.observe(ground(fn), np.zeros(2))
    return s


@pytest.mark.parametrize("slope_deg", [10.0, 20.0, 30.0])
def test_a_ramp_reads_as_its_own_slope_driving_up_it_or_across_it(slope_deg):
    s = seen(lambda x, y: math.tan(math.radians(slope_deg)) * x)
    up = s.steepest_deg(np.zeros(2), np.array([3.0, 0.0]))  # pitch
    across = s.steepest_deg(np.zeros(2), np.array([0.0, 3.0]))  # roll
    assert up == pytest.approx(slope_deg, abs=1.0)
    assert across == pytest.approx(slope_deg, abs=1.0)
    assert s.allows(np.zeros(2), np.array([3.0, 0.0])) == (slope_deg <= 25.0)


def test_a_step_vetoes_only_the_drives_that_cross_it():
    s = seen(lambda x, y: np.where(x > 2.0, 0.4, 0.0))  # a 0.4 m ledge 2 m ahead
    assert not s.allows(np.zeros(2), np.array([3.0, 0.0]))
    assert s.allows(np.zeros(2), np.array([1.5, 0.0]))  # stops before it
    assert s.allows(np.zeros(2), np.array([0.0, 3.0]))  # along it
    assert s.allows(np.zeros(2), np.array([-3.0, 0.0]))  # away from it


def test_ground_it_has_not_seen_passes():
    s = shield()
    assert s.steepest_deg(np.zeros(2), np.array([3.0, 0.0])) == 0.0  # nothing seen yet
    s.observe(ground(lambda x, y: 0.6 * x, half=1.0), np.zeros(2))  # 31 deg, but only within 1 m
    assert s.steepest_deg(np.array([3.0, 3.0]), np.array([2.0, 0.0])) == 0.0  # a drive far from it
    assert not s.allows(np.zeros(2), np.array([0.5, 0.0]))
    s.reset()
    assert s.allows(np.zeros(2), np.array([0.5, 0.0]))  # a new episode forgets the map


def test_choose_takes_the_first_allowed_of_the_top_k_and_counts_vetoes():
    s = seen(lambda x, y: np.where(x > 1.0, 0.5, 0.0))  # a wall 1 m ahead (+x)
    offsets = np.array([[3.0, 0.0], [0.0, 3.0], [2.0, 0.1], [-3.0, 0.0]])
    assert s.choose([0, 2, 1, 3], offsets, np.zeros(2)) == 1  # 0 and 2 cross the wall
    assert (s.decisions, s.vetoes) == (1, 1)
    assert s.choose([1, 0], offsets, np.zeros(2)) == 1  # the policy's own choice is allowed: no veto
    assert (s.decisions, s.vetoes) == (2, 1)


def test_choose_falls_back_to_the_policys_choice_beyond_top_k_or_when_all_are_vetoed():
    s = seen(lambda x, y: np.where(x > 1.0, 0.5, 0.0), top_k=2)
    offsets = np.array([[3.0, 0.0], [2.0, 0.1], [0.0, 3.0]])
    assert s.choose([0, 1, 2], offsets, np.zeros(2)) == 0  # the allowed one is third: out of reach
    assert (s.vetoes, s.fallbacks) == (0, 1)
    with pytest.raises(ValueError, match="at least one"):
        s.choose([], offsets, np.zeros(2))


RAMP_30 = lambda x, y: math.tan(math.radians(30.0)) * x  # noqa: E731  every drive pitches or rolls 30 degrees


def test_with_none_allowed_the_tilt_check_is_dropped_but_hazards_and_places_still_steer():
    """A rover on 30 degree ground sees every drive over the 25 degree limit; repeating the policy's choice (the
    drive that just halted) left it standing there. The first drive clear of hazards felt is driven instead,
    one that ends away from the places stood on first."""
    s = seen(RAMP_30, hazard_radius=0.5, revisit_radius=1.0)
    up, left, down, right = [3.0, 0.0], [0.0, 3.0], [-3.0, 0.0], [0.0, -3.0]
    offsets = np.array([up, left, down, right])
    assert s.steepest_many(np.zeros(2), offsets).min() > 25.0
    assert s.choose([0, 1, 2], offsets, np.zeros(2)) == 0  # nothing felt, nowhere stood: the policy's choice
    assert (s.fallbacks, s.vetoes) == (1, 0)
    s.mark_hazard(np.array([2.0, 0.0]))  # the tilt guard halted it up the slope
    assert s.choose([0, 1, 2], offsets, np.zeros(2)) == 1  # not up again: the next, left
    assert (s.fallbacks, s.vetoes) == (2, 1)
    # 3 m to the left, the policy asks to go back right, to the origin it stood on: the next fresh one instead
    assert s.choose([3, 0, 2], offsets, np.array([0.0, 3.0])) == 0
    assert (s.fallbacks, s.vetoes) == (3, 2)
    # every candidate passes near a hazard felt: the policy's choice, as before the rule
    s.mark_hazard(np.array([0.0, 3.0]))
    assert s.choose([0, 1], offsets, np.array([0.0, 3.0])) == 0 and (s.fallbacks, s.vetoes) == (4, 2)
    # an allowed candidate takes no fallback
    flat = seen(lambda x, y: 0.0 * x, hazard_radius=0.5)
    assert flat.choose([0, 1], offsets, np.zeros(2)) == 0 and flat.fallbacks == 0


def test_with_none_allowed_an_obstructed_drive_is_still_skipped():
    """A 0.3 m rock 1 m up a 30 degree ramp: the tilt check is dropped when nothing passes, the obstacle check
    is not."""
    rock = lambda x, y: RAMP_30(x, y) + np.where((np.abs(y) < 0.2) & (x > 1.0) & (x < 1.4), 0.3, 0.0)  # noqa: E731
    s = seen(rock, obstacle_height=0.1)
    offsets = np.array([[3.0, 0.0], [0.0, 3.0]])
    assert s.obstacle_m(np.zeros(2), offsets[0]) > 0.1 and s.obstacle_m(np.zeros(2), offsets[1]) < 0.1
    assert s.choose([0, 1], offsets, np.zeros(2)) == 1 and (s.fallbacks, s.vetoes) == (1, 1)


def test_the_place_rule_prefers_an_allowed_drive_that_does_not_end_where_the_rover_stood():
    s = seen(lambda x, y: np.zeros_like(x), revisit_radius=1.0, top_k=8)
    back, side, ahead = [-2.0, 0.0], [0.0, 2.0], [2.0, 0.0]
    offsets = np.array([back, side, ahead])
    assert s.choose([2, 0, 1], offsets, np.zeros(2)) == 2  # the first decision: nowhere stood yet
    # 2 m further on, the policy wants to go back to the start: the next allowed drive that ends elsewhere wins
    assert s.choose([0, 1, 2], offsets, np.array([2.0, 0.0])) == 1
    assert (s.decisions, s.vetoes, s.revisits) == (2, 1, 1)
    assert s.fresh(np.array([2.0, 0.0]), offsets).tolist() == [False, True, True]
    s.reset()  # a new episode forgets the places
    assert s.choose([0, 1, 2], offsets, np.array([2.0, 0.0])) == 0
    assert s.revisits == 1


def test_the_place_rule_drives_the_first_allowed_when_every_allowed_drive_returns():
    s = seen(lambda x, y: np.where(x > 3.0, 0.5, 0.0), revisit_radius=1.0)  # a wall 1 m ahead of x = 2
    offsets = np.array([[2.0, 0.0], [-2.0, 0.0], [-2.0, 0.1]])
    s.choose([0], offsets, np.zeros(2))  # stood at the origin
    # from x = 2: ahead crosses the wall, both others end at the origin: the first allowed, no place veto
    assert s.choose([0, 2, 1], offsets, np.array([2.0, 0.0])) == 2
    assert s.revisits == 0 and s.vetoes == 1


def test_without_a_revisit_radius_places_are_not_kept():
    s = seen(lambda x, y: np.zeros_like(x))
    offsets = np.array([[-2.0, 0.0], [0.0, 2.0]])
    s.choose([1], offsets, np.zeros(2))
    assert s.choose([0, 1], offsets, np.array([2.0, 0.0])) == 0  # back to the origin, as the policy asks
    assert s.fresh(np.array([2.0, 0.0]), offsets).all() and (s.vetoes, s.revisits) == (0, 0)


def ring(headings: int = 32, distances: tuple[float, ...] = (1.0, 2.0, 3.0)) -> np.ndarray:
    from diana_lab.core.candidates import candidate_offsets

    return candidate_offsets(headings, distances)


@pytest.mark.parametrize("goal", [(2.4, 0.9), (-1.3, 0.2), (0.4, -2.95), (1.0, 1.0)])
def test_the_final_approach_drives_the_shortest_candidate_passing_the_goal(goal):
    s = seen(lambda x, y: np.zeros_like(x), approach_radius=5.0, approach_tolerance=0.3, top_k=96)
    offsets, g = ring(), np.asarray(goal)
    k = s.choose(np.arange(96), offsets, np.zeros(2), g)  # the policy wants straight ahead (+x), 1 m
    o = offsets[k]
    t = np.clip(o @ g / (o @ o), 0.0, 1.0)
    assert np.hypot(*(t * o - g)) <= 0.3  # it passes the goal, within the tolerance
    # and no shorter candidate does
    for other in offsets[np.hypot(offsets[:, 0], offsets[:, 1]) < np.hypot(*o) - 1e-6]:
        t = np.clip(other @ g / (other @ other), 0.0, 1.0)
        assert np.hypot(*(t * other - g)) > 0.3
    assert (s.approaches, s.vetoes, s.decisions) == (1, 0, 1)


def test_beyond_reach_the_final_approach_drives_the_candidate_ending_nearest_the_goal():
    s = seen(lambda x, y: np.zeros_like(x), approach_radius=5.0, top_k=96)
    offsets = ring()
    goal = 4.5 * np.array([math.cos(0.2), math.sin(0.2)])  # 4.5 m out, 11.5 deg left: nearest the 2nd bearing
    k = s.choose(np.arange(96), offsets, np.zeros(2), goal)
    assert offsets[k] == pytest.approx(3.0 * np.array([math.cos(math.pi / 16), math.sin(math.pi / 16)]))
    assert s.choose(np.arange(96), offsets, np.zeros(2), np.array([5.2, 0.0])) == 0  # beyond approach_radius
    # only the candidates the shield is given (the policy's top_k) are driven
    assert s.choose([0, 1, 2], offsets, np.zeros(2), np.array([2.5, 1.0])) == 2  # 3 m ahead passes nearest
    assert s.approaches == 2


def test_the_final_approach_yields_to_the_checks_and_to_the_policy_without_a_goal():
    s = seen(lambda x, y: np.where(x > 1.0, 0.5, 0.0), approach_radius=5.0)  # a wall 1 m ahead (+x)
    offsets = ring()
    left = 8 * 3 + 2  # 3 m to the left (+y)
    k = s.choose([1, 2, left], offsets, np.zeros(2), np.array([2.5, 0.0]))  # the goal lies behind the wall
    assert k == left and s.approaches == 0 and s.vetoes == 1  # the way to it is vetoed: the policy's order
    assert s.choose([left], offsets, np.zeros(2)) == left  # no goal given: no approach
    off = seen(lambda x, y: np.zeros_like(x))  # approach_radius 0: off
    assert off.choose([left], offsets, np.zeros(2), np.array([2.5, 0.0])) == left and off.approaches == 0


def test_the_final_approach_ignores_the_place_rule():
    s = seen(lambda x, y: np.zeros_like(x), approach_radius=5.0, revisit_radius=1.0, top_k=96)
    offsets = ring()
    s.choose([0], offsets, np.zeros(2))  # stood at the origin
    # from 2 m ahead, the goal lies 0.2 m from where the rover stood: the approach drives back all the same
    k = s.choose(np.arange(96), offsets, np.array([2.0, 0.0]), np.array([0.2, 0.0]))
    assert offsets[k] == pytest.approx([-2.0, 0.0], abs=1e-9) and s.revisits == 0


def test_a_sidecar_written_before_the_final_approach_reads_it_as_off():
    from dataclasses import asdict

    node = asdict(ShieldSettings.from_config(ShieldConfig(enabled=True, approach_radius=5.0), ROBOT))
    older = {k: v for k, v in node.items() if k not in ("approach_radius", "approach_tolerance")}
    settings = ShieldSettings.from_dict(older)
    assert (settings.approach_radius, settings.approach_tolerance) == (0.0, 0.3)
    s = SlopeShield(settings)
    s.observe(ground(lambda x, y: np.zeros_like(x)), np.zeros(2))
    assert s.choose([5], ring(), np.zeros(2), np.array([2.0, 0.0])) == 5 and s.approaches == 0
    assert ShieldSettings.from_dict(node).approach_radius == 5.0


def test_a_sidecar_written_before_the_peak_reference_reads_it_as_the_median_of_seven_known():
    from dataclasses import asdict

    node = asdict(ShieldSettings.from_config(ShieldConfig(peak_height=0.08, peak_rank=2, peak_min_known=4), ROBOT))
    assert (node["peak_rank"], node["peak_min_known"]) == (2, 4)
    older = ShieldSettings.from_dict({k: v for k, v in node.items() if k not in ("peak_rank", "peak_min_known")})
    assert (older.peak_rank, older.peak_min_known, older.peak_height) == (0, 7, 0.08)
    with pytest.raises(ValueError, match=r"shield\.peak_min_known: expected an integer in 1\.\.8"):
        SlopeShield(ShieldSettings.from_dict({**node, "peak_min_known": 0}))


def test_a_hazard_felt_vetoes_the_drives_that_pass_near_it_until_reset():
    """Where the wheels met ground they could not drive (the tilt guard, a slope) is kept off, though the map
    shows flat ground there (what the rover tips on is often narrower than the map's cells)."""
    s = seen(lambda x, y: 0.0 * x, hazard_radius=0.5)
    start = np.zeros(2)
    offsets = np.array([[3.0, 0.0], [2.0, 0.3], [1.0, 0.0], [0.0, 3.0], [-1.0, 0.0], [3.0, 2.0]])
    assert s.near_hazard(start, offsets).tolist() == [False] * 6
    s.mark_hazard(np.array([2.0, 0.0]))
    s.mark_hazard(None)  # nothing felt this step
    # through it; ending 0.3 m aside of it; stopping 1 m short, across, away and well aside: allowed
    assert s.near_hazard(start, offsets).tolist() == [True, True, False, False, False, False]
    assert not s.allows(start, offsets[0]) and s.allows(start, offsets[2])
    assert s.choose([0, 1, 5, 2], offsets, start) == 5 and s.vetoes == 1
    # a rover held just short of it may leave it, or pass aside, but not drive on towards it
    near = s.near_hazard(np.array([1.8, 0.0]), np.array([[-2.0, 0.0], [0.0, 1.0], [1.0, 0.0], [0.15, 0.0]]))
    assert near.tolist() == [False, False, True, True]
    # held 0.05 m short of it (closer than a check every `spacing`): on through it is closer, so vetoed
    assert s.near_hazard(np.array([1.95, 0.0]), np.array([[1.0, 0.0], [-1.0, 0.0]])).tolist() == [True, False]
    s.reset()
    assert s.near_hazard(start, offsets).tolist() == [False] * 6


def test_a_rock_beside_the_tracks_is_an_obstacle_the_tilt_check_alone_lets_through():
    """A 0.3 m rock 0.2-0.4 m to the left of the drive: under the footprint (radius 0.33 m) but beside the left
    track (0.19 m), so the roll the map shows stays under the limit; the obstacle check vetoes it."""
    rock = lambda x, y: np.where((y > 0.2) & (y < 0.4) & (x > 1.0) & (x < 1.4), 0.3, 0.0)  # noqa: E731
    start, through, away = np.zeros(2), np.array([3.0, 0.0]), np.array([0.0, -3.0])
    plain = seen(rock)
    assert plain.steepest_deg(start, through) < 25.0 and plain.allows(start, through)  # the check off: passes
    s = seen(rock, obstacle_height=0.12)
    assert 0.12 < s.obstacle_m(start, through) <= 0.3 + 1e-6
    assert not s.allows(start, through)
    assert s.obstacle_m(start, away) == 0.0 and s.allows(start, away)
    assert s.choose([0, 1], np.array([through, away]), start) == 1 and s.vetoes == 1
    assert s.obstacle_m(np.array([5.0, 5.0]), through) == 0.0  # nothing known of that way: passes


@pytest.mark.parametrize("rank", [0, 2])
def test_a_rock_under_the_axle_probes_is_a_peak_the_obstacle_check_misses(rank):
    """A 0.25 m rock one 0.2 m cell wide on the drive's centre line: the axle probes, the obstacle check's
    reference, read the rock's own (bilinearly smeared) height, so the rise it measures stays under 0.12 m (the
    craters collisions the obstacle check let through, docs/reference_policy.md, "What is left"); the rock's cell
    stands over its neighbours' median, and over the second highest of them, by its whole height: the peak check
    vetoes the drive with either reference."""
    rock = lambda x, y: np.where((y > 0.0) & (y < 0.2) & (x > 1.2) & (x < 1.4), 0.25, 0.0)  # noqa: E731
    start, through, away = np.zeros(2), np.array([3.0, 0.0]), np.array([0.0, -3.0])
    s = seen(rock, obstacle_height=0.12, peak_height=0.10, peak_rank=rank)
    assert s.obstacle_m(start, through) <= 0.12 and s.peak_m(start, through) == pytest.approx(0.25, abs=1e-6)
    assert not s.allows(start, through)
    assert s.peak_m(start, away) == 0.0 and s.allows(start, away)
    assert s.choose([0, 1], np.array([through, away]), start) == 1
    assert seen(rock, obstacle_height=0.12).allows(start, through)  # without the peak check it passes


@pytest.mark.parametrize(
    "name, fn",
    [
        ("slope", lambda x, y: math.tan(math.radians(24.0)) * x),
        ("ridge", lambda x, y: 0.3 - math.tan(math.radians(30.0)) * np.abs(x - 1.5)),  # a 30 deg crest across
        ("step", lambda x, y: np.where(x > 1.5, 0.3, 0.0)),  # a ledge: half the neighbours up, half down
    ],
)
def test_slopes_ridges_and_steps_are_not_peaks(name, fn):
    """Not at the preset's 0.10 m: a cell on a slope or a step has neighbours above and below it; on a crest,
    the two along it are as high, so the median sits at most halfway down its sides."""
    s = seen(fn, peak_height=0.10)
    assert s.peak_m(np.zeros(2), np.array([3.0, 0.0])) <= 0.07, name


def test_a_sharp_crest_stands_over_its_median_but_not_over_its_second_highest_neighbour():
    """A 60 deg crest (a crater rim's knife edge): each map cell keeps its highest return, so the cells either
    side of the crest's stand 0.17 m lower, six of its eight neighbours: the median flags the crest as a 0.17 m
    peak, while the two cells along it, as high as it, leave nothing over the second highest (``peak_rank`` 2;
    the crest is driven across, where rocks are vetoed either way)."""
    crest = lambda x, y: 0.5 - math.tan(math.radians(60.0)) * np.abs(x - 1.5)  # noqa: E731  # crest mid-cell
    start, across = np.zeros(2), np.array([3.0, 0.0])
    median = seen(crest, peak_height=0.10, limit_deg=80.0)  # the tilt check aside: its 60 deg flanks
    assert median.peak_m(start, across) == pytest.approx(0.1 * math.tan(math.radians(60.0)), abs=0.01)
    assert not median.allows(start, across)
    second = seen(crest, peak_height=0.10, limit_deg=80.0, peak_rank=2)
    assert second.peak_m(start, across) == pytest.approx(0.0, abs=1e-6) and second.allows(start, across)


@pytest.mark.parametrize(("rank", "flagged"), [(1, False), (2, True), (3, True)])
def test_a_rock_two_cells_wide_is_a_peak_over_all_but_its_own_other_cell(rank, flagged):
    """A 0.3 m rock over two 0.2 m cells: each cell has the other among its neighbours, as high as itself, so it
    stands over the second highest neighbour (and the third) by the rock's height, not over the highest."""
    from diana_lab.core.height_memory import HeightMemory

    m = HeightMemory(0.2, 4.0, 1, 1, 0.0, 0.0)
    rock = lambda x, y: np.where((x > 0.0) & (x < 0.4) & (y > 0.0) & (y < 0.2), 0.3, 0.0)  # noqa: E731
    m.update(ground(rock, half=1.0), np.zeros(2))
    got = m.peaks_at(np.array([0.1, 0.3]), np.array([0.1, 0.1]), rank=rank)
    assert got.tolist() == pytest.approx([0.3, 0.3] if flagged else [0.0, 0.0], abs=1e-6)


def test_a_peak_beside_unseen_ground_is_not_judged():
    """A cell needs 7 of its 8 neighbours known: a rock whose far side was never seen (its shadow) is not judged
    by it, nor is a map with nothing around the cell."""
    from diana_lab.core.height_memory import HeightMemory

    m = HeightMemory(0.2, 4.0, 1, 1, 0.0, 0.0)  # cells 0.2 m from (-4, -4): the rock's is [0, 0.2) x [0, 0.2)
    pts = ground(lambda x, y: np.where((x > 0.0) & (x < 0.2) & (y > 0.0) & (y < 0.2), 0.3, 0.0), half=1.0)
    m.update(pts[pts[:, 0] < 0.2], np.zeros(2))  # the rock's cell and the ground on its near side only
    rock_x, rock_y = np.array([0.1]), np.array([0.1])
    assert m.peaks_at(rock_x, rock_y)[0] == 0.0  # 5 of 8 neighbours known
    assert m.peaks_at(rock_x, rock_y, min_known=5)[0] == pytest.approx(0.3, abs=1e-6)
    assert m.peaks_at(rock_x, rock_y, min_known=5, rank=2)[0] == pytest.approx(0.3, abs=1e-6)
    assert m.peaks_at(rock_x, rock_y, min_known=1, rank=6)[0] == 0.0  # only 5 known: no 6th highest to judge by
    with pytest.raises(ValueError, match=r"min_known in 1\.\.8 and rank in 0\.\.8"):
        m.peaks_at(rock_x, rock_y, min_known=0)
    with pytest.raises(ValueError, match=r"min_known in 1\.\.8 and rank in 0\.\.8"):
        m.peaks_at(rock_x, rock_y, rank=9)
    m.update(pts, np.zeros(2))
    # seen all round it is; the map's edge cell and a flat cell are not peaks
    got = m.peaks_at(np.array([0.1, 3.9, 0.5]), np.array([0.1, 3.9, 0.5]))
    assert got.tolist() == pytest.approx([0.3, 0.0, 0.0], abs=1e-6)


def test_one_lookup_for_both_checks_gives_the_verdicts_of_each_check_alone():
    """allows() reads the tilt and the obstacle rise from one map lookup; on rough, partly seen ground its
    verdict for every candidate drive is the one the separate checks (steepest_deg, obstacle_m) give."""
    rng = np.random.default_rng(3)
    heights, centres = rng.uniform(0.0, 0.25, 40), rng.uniform(-5.0, 5.0, (40, 2))

    def rough(x, y):
        z = 0.15 * np.sin(0.9 * x) * np.cos(0.7 * y)
        for (cx, cy), h in zip(centres, heights):
            z = np.where(np.hypot(x - cx, y - cy) < 0.25, z + h, z)
        return z

    s = shield(obstacle_height=0.08, limit_deg=12.0)
    pts = ground(rough)
    s.observe(pts[pts[:, 0] < 3.0], np.zeros(2))  # beyond x = 3 m: never seen
    angles = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    verdicts, by_rise = [], []
    for start in rng.uniform(-3.0, 3.0, (6, 2)):
        for length in (1.0, 2.0, 3.0):
            for a in angles:
                offset = length * np.array([math.cos(a), math.sin(a)])
                level, low = s.steepest_deg(start, offset) <= 12.0, s.obstacle_m(start, offset) <= 0.08
                assert s.allows(start, offset) == (level and low)
                verdicts.append(level and low)
                by_rise.append(level and not low)
    assert 0.2 < np.mean(verdicts) < 0.8  # the ground vetoes some drives and lets others through
    assert np.mean(by_rise) > 0.05  # and some only for what rises above the wheels


def test_each_veto_is_put_down_to_every_check_the_policys_choice_failed():
    """``vetoed_by``: a steep ramp (tilt), a wide rock beside the tracks (obstacle), a one-cell rock under the axle
    probes (peak), a hazard felt, a place stood on; a drive failing two checks counts under both, and a decision
    that drives the policy's choice counts under none."""

    def ground_fn(x, y):
        ramp = np.where(x < -1.0, math.tan(math.radians(28.0)) * (-1.0 - x), 0.0)  # west of x = -1: 28 deg up
        # east, beside the tracks: 2 x 3 cells, so no cell of it stands over its second-highest neighbour
        beside = np.where((y > 0.2) & (y < 0.6) & (x > 1.0) & (x < 1.6), 0.3, 0.0)
        under = np.where((x > 0.0) & (x < 0.2) & (y > 1.2) & (y < 1.4), 0.25, 0.0)  # north: one cell
        return ramp + beside + under

    s = seen(ground_fn, obstacle_height=0.12, peak_height=0.08, peak_rank=2, hazard_radius=0.5, revisit_radius=1.0)
    start = np.zeros(2)
    east, north, west, south = [3.0, 0.0], [0.0, 3.0], [-3.0, 0.0], [0.0, -3.0]
    offsets = np.array([east, north, west, south])
    assert s.failed_checks(start, offsets[0]) == ("obstacle",)
    assert s.failed_checks(start, offsets[1]) == ("peak",)
    assert s.failed_checks(start, offsets[2]) == ("tilt",)
    assert s.failed_checks(start, offsets[3]) == ()
    assert s.choose([3], offsets, start) == 3 and sum(s.vetoed_by.values()) == 0  # driven: no veto
    for first, check in ((0, "obstacle"), (1, "peak"), (2, "tilt")):
        assert s.choose([first, 3], offsets, np.zeros(2)) == 3
        assert s.vetoed_by[check] == 1
    assert s.vetoes == 3 and s.vetoed_by["hazard"] == s.vetoed_by["place"] == 0
    s.mark_hazard(np.array([2.0, 0.3]))  # now east is near a hazard felt as well as obstructed
    assert s.failed_checks(start, offsets[0]) == ("hazard", "obstacle")
    assert s.choose([0, 3], offsets, start) == 3
    assert (s.vetoed_by["hazard"], s.vetoed_by["obstacle"], s.vetoes) == (1, 2, 4)
    # 3 m south the policy asks to go back north to the origin, where the rover stood: the place rule
    back, aside = [0.0, 3.0], [3.0, 0.0]
    assert s.failed_checks(np.array([0.0, -3.0]), np.array(back)) == ()
    assert s.choose([0, 1], np.array([back, aside]), np.array([0.0, -3.0])) == 1
    assert s.vetoed_by["place"] == 1 and s.vetoes == 5 and s.revisits == 1
    assert sum(s.vetoed_by.values()) == 6  # one veto failed two checks


def test_returns_near_the_sensor_are_left_out_of_the_map_with_min_range():
    """A dust return 0.6 m from the sensor, floating 0.3 m above the ground beside the rover, would read as a
    ledge under the next drive; with min_range 1 m it is not mapped (the ground farther out still is)."""
    sensor = np.array([0.0, 0.0, 0.5])
    floor = ground(lambda x, y: 0.0 * x, half=3.0)
    dust = np.array([[0.45, 0.0, 0.3]])  # 0.49 m from the sensor
    level = (0.0, 0.0, 0.0)
    for min_range, vetoed in ((0.0, True), (1.0, False)):
        s = shield(min_range=min_range)
        s.observe_rover(np.vstack([floor, dust]), (0.0, 0.0, 0.0), level, sensor)
        assert (not s.allows(np.zeros(2), np.array([2.0, 0.0]))) == vetoed
        assert s.memory.heights_at(np.array([2.5]), np.array([0.0]))[1][0]  # far ground is mapped either way
    with pytest.raises(ValueError, match="sensor_xyz"):
        shield(min_range=1.0).observe_rover(floor, (0.0, 0.0, 0.0), level)


def test_far_points_are_the_rows_far_enough_whatever_frame_they_are_in():
    """``far_points`` selects rows of any array by the rover-frame returns' distance: the boolean selection's
    rows, and the array itself (no copy) when every return is far enough."""
    s = shield(min_range=1.0)
    sensor = np.array([0.2, 0.0, 0.3])
    rover = np.random.default_rng(4).uniform(-3.0, 3.0, (500, 3)).astype(np.float32)
    world = rover + np.float32(10.0)  # the same returns elsewhere
    keep = s.far_enough(rover, sensor)
    assert 0 < keep.sum() < len(rover)
    np.testing.assert_array_equal(s.far_points(world, rover, sensor), world[keep])
    far = rover[keep]
    assert s.far_points(far + 10.0, far, sensor).shape == far.shape
    same = far + np.float32(10.0)
    assert s.far_points(same, far, sensor) is same


SMOOTH = {"obstacle_height": 0.12, "smooth_roughness": 0.0045, "smooth_obstacle_height": 0.06}
LOW_ROCK = 0.19  # smeared over the 0.2 m cells: it rises 0.06-0.12 m above the wheels


def _low_rock(x, y):
    return np.where((y > 0.2) & (y < 0.4) & (x > 1.0) & (x < 1.4), LOW_ROCK, 0.0)  # beside the left track


def _bumps(x, y):
    """Relief of +-1 cm in 0.8 m tiles (1 cm of roughness on the shield's 2 x 2-cell blocks): drivable, but not
    smooth."""
    ix, iy = np.floor(x / 0.8).astype(int), np.floor(y / 0.8).astype(int)
    return 0.01 * np.where((ix + iy) % 2 == 0, 1.0, -1.0)


def _speckle(x, y):
    """+-1 cm from one 0.2 m cell to the next, as range noise leaves it: the blocks' means cancel it."""
    ix, iy = np.floor(x / 0.2).astype(int), np.floor(y / 0.2).astype(int)
    return 0.01 * np.where((ix + iy) % 2 == 0, 1.0, -1.0)


def test_on_smooth_ground_a_low_rock_is_vetoed_as_smooth_and_on_rough_ground_let_through():
    """A rise between the two limits is a rock only where the ground round it is smooth; on ground whose own
    relief is rough the same rise is let through, as it is with the rule off."""
    start, through, away = np.zeros(2), np.array([3.0, 0.0]), np.array([0.0, -3.0])
    off = seen(_low_rock, obstacle_height=0.12)
    assert 0.06 < off.obstacle_m(start, through) < 0.12 and off.allows(start, through)
    s = seen(_low_rock, **SMOOTH)
    assert s.smooth_ground(start) and s.memory.roughness_near(0.0, 0.0, 8) < 1e-5
    assert s.failed_checks(start, through) == ("smooth",) and s.failed_checks(start, away) == ()
    assert s.choose([0, 1], np.array([through, away]), start) == 1
    assert s.vetoes == 1 and s.vetoed_by["smooth"] == 1 and s.vetoed_by["obstacle"] == 0
    rough = seen(lambda x, y: _low_rock(x, y) + _bumps(x, y), **SMOOTH)
    assert rough.memory.roughness_near(0.0, 0.0, 8) > 0.0045 and not rough.smooth_ground(start)
    assert 0.06 < rough.obstacle_m(start, through) < 0.12
    assert rough.failed_checks(start, through) == ()
    speckled = seen(lambda x, y: _low_rock(x, y) + _speckle(x, y), **SMOOTH)  # cell-scale noise: still smooth
    assert speckled.smooth_ground(start) and speckled.failed_checks(start, through) == ("smooth",)
    tall = seen(lambda x, y: 0.3 * (_low_rock(x, y) > 0) + _bumps(x, y), **SMOOTH)
    assert tall.failed_checks(start, through) == ("obstacle",)  # over obstacle_height: rough ground or not


def test_the_smooth_ground_verdict_follows_the_map_and_the_place():
    s = seen(_low_rock, **SMOOTH)
    assert s.smooth_ground(np.zeros(2))
    s.observe(ground(_bumps), np.zeros(2))  # the same place seen again, now rough
    assert not s.smooth_ground(np.zeros(2))
    assert not s.smooth_ground(np.array([40.0, 0.0]))  # nothing known there: not smooth
    s.reset()
    assert not s.smooth_ground(np.zeros(2))
    assert not seen(_low_rock, obstacle_height=0.12).smooth_ground(np.zeros(2))  # the rule off


def test_a_sidecar_written_before_the_smooth_ground_limit_reads_it_as_off():
    from dataclasses import asdict

    node = asdict(ShieldSettings.from_config(ShieldConfig(enabled=True, **SMOOTH), ROBOT))
    older = {k: v for k, v in node.items() if not k.startswith("smooth_")}
    s = SlopeShield(ShieldSettings.from_dict(older))
    s.observe(ground(_low_rock), np.zeros(2))
    assert s.cfg.smooth_roughness == 0.0 and s.allows(np.zeros(2), np.array([3.0, 0.0]))
    with pytest.raises(ValueError, match=r"shield\.smooth_obstacle_height: with shield\.smooth_roughness > 0"):
        SlopeShield(ShieldSettings.from_dict({**node, "smooth_obstacle_height": 0.12}))


def test_without_a_hazard_radius_hazards_are_not_kept():
    s = seen(lambda x, y: 0.0 * x)  # hazard_radius 0 (the default)
    s.mark_hazard(np.array([2.0, 0.0]))
    assert len(s.hazards) == 0 and s.allows(np.zeros(2), np.array([3.0, 0.0]))


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("cell_size", 0.0),
        ("spacing", -0.1),
        ("radius", 0.0),
        ("limit_deg", 0.0),
        ("limit_deg", 90.0),
        ("top_k", 0),
        ("hazard_radius", -0.5),
        ("obstacle_height", -0.1),
        ("min_range", -1.0),
        ("revisit_radius", -0.5),
        ("peak_height", -0.1),
        ("approach_radius", -1.0),
        ("approach_tolerance", 0.0),
        ("peak_rank", -1),
        ("peak_rank", 9),
        ("peak_rank", 1.5),
        ("peak_min_known", 0),
        ("peak_min_known", 9),
        ("peak_min_known", True),
        ("smooth_roughness", -0.001),
        ("smooth_obstacle_height", -0.05),
        ("smooth_radius", 0.0),
        ("relief_slope_deg", 0.0),
        ("relief_slope_deg", 90.0),
        ("relief_step", 0.0),
        ("relief_roughness", -0.01),
        ("relief_min_known", 2),
        ("relief_min_known", 8.5),
        ("relief_min_known", True),
        ("relief_unseen_from", -0.5),
    ],
)
def test_bad_settings_name_their_key(key, value):
    with pytest.raises(ConfigError, match=f"eval.shield.{key}"):
        ShieldConfig(**{key: value})


def test_the_unseen_veto_without_the_relief_check_is_refused():
    with pytest.raises(ConfigError, match=r"eval.shield.relief_unseen_from=0.8: expected eval.shield.relief=true"):
        ShieldConfig(relief_unseen_from=0.8)
    assert ShieldConfig(relief=True, relief_unseen_from=0.8).relief_unseen_from == 0.8


@pytest.mark.parametrize("low", [0.0, 0.12, 0.2])
def test_a_smooth_ground_limit_must_lie_under_the_obstacle_height(low):
    with pytest.raises(ConfigError, match=r"eval.shield.smooth_obstacle_height: .*below eval.shield.obstacle_height"):
        ShieldConfig(obstacle_height=0.12, smooth_roughness=0.004, smooth_obstacle_height=low)


RAMP = math.tan(math.radians(23.5))  # between the relief check's 22 deg and the tilt check's 25


def _ramp_east(x, y):
    return RAMP * np.clip(x - 2.0, 0.0, None)


def test_the_relief_check_vetoes_a_drive_the_tilt_check_lets_through():
    east, north = np.array([3.0, 0.0]), np.array([0.0, 3.0])
    plain = seen(_ramp_east)
    assert plain.failed_checks(np.zeros(2), east) == ()  # the tilt check alone: allowed
    s = seen(_ramp_east, relief=True)
    assert s.failed_checks(np.zeros(2), east) == ("relief",)
    assert s.failed_checks(np.zeros(2), np.array([1.0, 0.0])) == ()  # stops short of it
    assert s.failed_checks(np.zeros(2), north) == ()  # beside it
    assert s.choose([0, 1], np.array([east, north]), np.zeros(2)) == 1
    assert (s.vetoes, s.vetoed_by["relief"], s.vetoed_by["tilt"]) == (1, 1, 0)
    many = np.array([east, north, [2.5, 1.0], [-3.0, 0.0]])
    np.testing.assert_array_equal(s.relief_crosses(np.zeros(2), many), [True, False, True, False])


def test_a_kerb_is_relief_where_the_ground_is_judged():
    s = seen(lambda x, y: np.where(x > 2.0, 0.2, 0.0), relief=True)  # 0.2 m: a step whatever the plane
    assert s.failed_checks(np.zeros(2), np.array([3.0, 0.0]))[:2] == ("tilt", "relief")


def test_the_relief_check_reads_the_mean_returns_not_the_highest():
    """Past x = 2 every cell's returns scatter 0.1 m either side of the flat ground (range noise): their mean is
    the ground, their highest a 0.1 m kerb that is not there."""
    flat = ground(lambda x, y: 0.0 * x)
    far = flat[flat[:, 0] > 2.0]
    up = np.array([0.0, 0.0, 0.1])
    noisy = np.concatenate([flat[flat[:, 0] <= 2.0], far + up, far - up])
    s = shield(relief=True)
    s.observe(noisy, np.zeros(2))
    assert not s.relief_crosses(np.zeros(2), np.array([[3.0, 0.0], [2.5, 1.0]])).any()
    n = s.memory.n
    on_highest = relief_hazards(s.memory.height.reshape(n, n), (0, 0, n, n), s.memory.cell_size, s.relief)
    assert on_highest.any()  # the same check on the highest returns: a kerb


def test_without_the_relief_check_the_map_keeps_no_mean_layer_and_nothing_crosses():
    s = seen(_ramp_east)
    assert s.memory.mean_height is None and s.relief is None
    assert not s.relief_crosses(np.zeros(2), np.array([[3.0, 0.0]])).any()
    assert not shield(relief=True).relief_crosses(np.zeros(2), np.array([[3.0, 0.0]])).any()  # no map yet


def test_the_relief_checks_fallback_drops_it_with_the_tilt_check():
    """Every drive crosses relief (the rover stands in a bowl of 23.5 deg the tilt check allows): the fallback
    drives, as on ground the tilt check vetoes everywhere."""
    s = seen(lambda x, y: RAMP * np.clip(np.hypot(x, y) - 0.8, 0.0, None), relief=True)
    offsets = np.array([[3.0, 0.0], [0.0, 3.0], [-3.0, 0.0]])
    assert s.relief_crosses(np.zeros(2), offsets).all()
    assert s.choose([1, 0, 2], offsets, np.zeros(2)) == 1 and s.fallbacks == 1


def _flat(x, y):
    return 0.0 * x


def test_ground_the_relief_check_cannot_judge_vetoes_a_drive_only_beyond_relief_unseen_from():
    """Flat ground seen out to 2 m, with a 0.4 m hole at (1, 1): with ``relief_unseen_from`` 1.5 m the drive
    out past the seen ground is vetoed, the one across the nearby hole is not."""
    points = ground(_flat, half=2.0)
    points = points[np.hypot(points[:, 0] - 1.0, points[:, 1] - 1.0) > 0.4]
    drives = np.array([[3.0, 0.0], [1.5, 0.0], [1.0, 1.0], [0.0, 3.0], [0.0, 1.8]])
    for unseen_from, vetoed in ((1.5, [True, False, False, True, False]), (0.0, [False] * 5), (3.5, [False] * 5)):
        s = shield(relief=True, relief_unseen_from=unseen_from)
        s.observe(points, np.zeros(2))
        np.testing.assert_array_equal(s.relief_crosses(np.zeros(2), drives), vetoed, err_msg=f"{unseen_from}")
    s = shield(relief=True, relief_unseen_from=1.5)
    s.observe(points, np.zeros(2))
    assert s.choose([0, 1], drives, np.zeros(2)) == 1 and s.vetoed_by["relief"] == 1
    nearer = shield(relief=True, relief_unseen_from=1.0)  # the hole lies 1.0..1.8 m along the diagonal
    nearer.observe(points, np.zeros(2))
    assert nearer.relief_crosses(np.zeros(2), np.array([[1.0, 1.0], [0.5, 0.5]])).tolist() == [True, False]


def test_ground_beyond_the_map_is_unjudged():
    s = shield(relief=True, relief_unseen_from=1.0, radius=3.0)
    s.observe(ground(_flat, half=8.0), np.zeros(2))
    assert s.relief_crosses(np.array([2.0, 0.0]), np.array([[-3.0, 0.0], [3.0, 0.0]])).tolist() == [False, True]


def test_a_sidecar_written_before_the_relief_check_reads_it_as_off():
    node = dataclasses.asdict(ShieldSettings.from_config(ShieldConfig(enabled=True, relief=True), ROBOT))
    assert node["relief"] is True
    for key in ("relief", "relief_slope_deg", "relief_step", "relief_roughness", "relief_min_known"):
        node.pop(key)
    assert SlopeShield(ShieldSettings.from_dict(node)).relief is None


def test_a_sidecar_written_before_the_unseen_veto_reads_it_as_off():
    node = dataclasses.asdict(ShieldSettings.from_config(ShieldConfig(relief=True, relief_unseen_from=0.8), ROBOT))
    assert node["relief_unseen_from"] == 0.8
    node.pop("relief_unseen_from")
    s = SlopeShield(ShieldSettings.from_dict(node))
    assert s.relief is not None and s.cfg.relief_unseen_from == 0.0
    with pytest.raises(ValueError, match="relief_unseen_from"):
        SlopeShield(ShieldSettings.from_dict({**node, "relief_unseen_from": -1.0}))
