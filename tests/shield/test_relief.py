"""The relief check's estimator (diana_lab.shield.relief) and the mean layer of the height map it reads."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diana_lab.core.height_memory import HeightMemory
from diana_lab.shield.relief import ReliefLimits, footprint_cells, relief_hazards, relief_judgement

CELL = 0.2
LIMITS = ReliefLimits(slope_deg=22.0, step=0.08, roughness=0.065, footprint_radius=0.433, min_known=8)
N = 40
XS = (np.arange(N) + 0.5) * CELL
X, Y = np.meshgrid(XS, XS)  # [iy, ix]


def hazards(grid: np.ndarray, limits: ReliefLimits = LIMITS) -> np.ndarray:
    return relief_hazards(grid, (0, 0, N, N), CELL, limits)


def test_the_footprint_at_0_2_m_is_13_cells():
    cells = footprint_cells(CELL, 0.433)
    assert len(cells) == 13 and (0, 0) in cells and (2, 0) in cells and (2, 1) not in cells


@pytest.mark.parametrize(
    ("slope_deg", "flagged"), [(0.0, False), (10.0, False), (20.0, False), (24.0, True), (35.0, True)]
)
def test_a_plane_is_a_hazard_only_past_the_slope_limit(slope_deg, flagged):
    # turned 30 deg, so that the slope runs along neither grid axis
    a = math.radians(30.0)
    grid = math.tan(math.radians(slope_deg)) * (math.cos(a) * X + math.sin(a) * Y) + 3.0
    inner = hazards(grid)[3:-3, 3:-3]
    assert inner.all() if flagged else not inner.any()


@pytest.mark.parametrize(("height", "flagged"), [(0.05, False), (0.15, True)])
def test_a_step_is_a_hazard_along_it_and_nowhere_else(height, flagged):
    grid = np.where(X > 4.0, height, 0.0)
    h = hazards(grid)
    assert h[3:-3, 18:22].all() == flagged  # the cells whose footprints straddle the step (between 19 and 20)
    assert not h[:, :17].any() and not h[:, 23:].any()  # ground farther from it


def test_a_step_on_a_slope_is_judged_against_the_slope():
    tilt = math.tan(math.radians(15.0)) * X
    assert not hazards(tilt).any()  # 15 deg, rising 0.054 m a cell: no step
    assert hazards(tilt + np.where(Y > 4.0, 0.15, 0.0))[19:23, 3:-3].any()


def test_rough_ground_is_a_hazard_smooth_bumps_are_not():
    rng = np.random.default_rng(0)
    assert hazards(rng.normal(0.0, 0.1, X.shape))[3:-3, 3:-3].mean() > 0.9
    gentle = 0.02 * np.sin(X * 2.0) * np.cos(Y * 2.0)  # 2 cm bumps a few metres across
    assert not hazards(gentle).any()


def test_unknown_ground_and_thin_footprints_are_not_judged():
    grid = np.where(X > 4.0, 0.3, 0.0)
    grid[:, 18:22] = np.nan  # the ground either side of the step unseen
    sparse = np.where(X > 4.0, 0.3, 0.0)
    sparse[::2, :] = np.nan  # every other row unseen
    assert not hazards(grid)[:, 18:22].any()  # unknown cells are never hazards
    assert not hazards(sparse).any()  # fewer than 8 known in every footprint
    assert hazards(sparse, ReliefLimits(22.0, 0.08, 0.065, 0.433, min_known=5)).any()


def test_the_judgement_says_which_cells_were_judged():
    grid = np.where(X > 4.0, 0.3, 0.0)
    grid[:, 25:] = np.nan  # unseen past x = 5 m
    grid[10, 5] = np.nan  # one unseen cell amid seen ground
    hazard, judged = relief_judgement(grid, (0, 0, N, N), CELL, LIMITS)
    np.testing.assert_array_equal(hazard, hazards(grid))
    assert not judged[:, 25:].any()  # no height of its own
    assert judged[3:-3, 3:22].sum() == judged[3:-3, 3:22].size - 1  # all seen ground but the one hole
    assert not judged[10, 5]
    assert judged[3:-3, 24].all()  # the last seen column: 9 of its 13 footprint cells known
    stricter = ReliefLimits(22.0, 0.08, 0.065, 0.433, min_known=10)
    _, judged_10 = relief_judgement(grid, (0, 0, N, N), CELL, stricter)
    assert judged_10[3:-3, 23].all() and not judged_10[:, 24].any()  # 12 known, then 9 < 10
    assert not (hazard & ~judged).any()


def test_a_box_reaching_off_the_grid_gives_its_own_shape_and_agrees_inside():
    grid = np.where(X > 4.0, 0.3, 0.0)
    whole = hazards(grid)
    part = relief_hazards(grid, (15, -3, 50, 12), CELL, LIMITS)
    assert part.shape == (15, 35)
    np.testing.assert_array_equal(part[3:15, 0:25], whole[0:12, 15:40])
    assert not part[:, 25:].any() and not part[:3].any()  # off the grid: unknown
    assert relief_hazards(grid, (5, 5, 5, 9), CELL, LIMITS).shape == (4, 0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"slope_deg": 0.0},
        {"slope_deg": 90.0},
        {"step": 0.0},
        {"roughness": -0.1},
        {"footprint_radius": 0.0},
        {"min_known": 2},
    ],
)
def test_bad_limits_are_refused(kwargs):
    base = {"slope_deg": 22.0, "step": 0.08, "roughness": 0.065, "footprint_radius": 0.433, "min_known": 8}
    with pytest.raises(ValueError, match="ReliefLimits"):
        ReliefLimits(**{**base, **kwargs})


def memory(mean: bool = True) -> HeightMemory:
    return HeightMemory(CELL, 2.0, 1, 1, 0.0, 0.0, mean=mean)


def test_the_mean_layer_pools_each_cells_returns_over_the_episode_beside_the_latest_highest():
    m = memory()
    frame = np.array([[0.05, 0.05, 1.0], [0.1, 0.1, 2.0], [0.15, 0.12, 3.0], [0.5, 0.5, 7.0]], np.float32)
    m.update(frame, np.zeros(2))
    cell = m._cells(np.array([0.1]), np.array([0.1]))[0][0]
    other = m._cells(np.array([0.5]), np.array([0.5]))[0][0]
    assert m.height[cell] == 3.0 and m.mean_height[cell] == pytest.approx(2.0)
    assert m.mean_height[other] == pytest.approx(7.0)
    assert np.isfinite(m.mean_height).sum() == 2
    m.update(np.array([[0.1, 0.05, 5.0]], np.float32), np.zeros(2))  # a later frame: pooled with the first's
    assert m.height[cell] == 5.0 and m.mean_height[cell] == pytest.approx(2.75)
    m.reset()
    assert np.isnan(m.mean_height).all()
    assert memory(mean=False).mean_height is None
