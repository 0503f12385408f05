"""Footprint hazards: a plane has its own slope and no step or roughness; bumps show up as both."""

from __future__ import annotations

import numpy as np
import pytest

from diana_lab.planning import terrain_hazards
from diana_lab.planning.hazards import footprint_mask
from diana_lab.sim.terrain import Terrain


def test_footprint_covers_the_robot_disc():
    mask = footprint_mask(0.33, 0.2, 0.2)
    oy, ox = np.mgrid[: mask.shape[0], : mask.shape[1]] - np.array(mask.shape)[:, None, None] // 2
    dist = np.hypot(ox * 0.2, oy * 0.2)
    assert np.all(mask[dist <= 0.33]) and not np.any(mask[dist > 0.33 + 0.1 + 1e-9])
    assert footprint_mask(0.01, 0.2, 0.2).sum() == 9  # never less than the 8 neighbours


@pytest.mark.parametrize("slope_deg", [0.0, 12.0, 40.0])
def test_tilted_plane(slope_deg):
    n, size = 81, 16.0
    x = -size / 2 + np.arange(n) * size / (n - 1)
    gx, gy = np.meshgrid(x, x)
    direction = np.radians(30.0)
    h = np.tan(np.radians(slope_deg)) * (np.cos(direction) * gx + np.sin(direction) * gy)
    hz = terrain_hazards(Terrain(h + 3.0, size, size), radius=0.33)
    assert np.allclose(hz.slope_deg, slope_deg, atol=1e-6)  # edges included: odd reflection keeps the plane
    assert np.allclose(hz.step, 0.0, atol=1e-9) and np.allclose(hz.roughness, 0.0, atol=1e-6)


def test_a_bump_is_a_step_and_roughness_only_near_it():
    h = np.zeros((81, 81))
    h[40, 40] = 0.2
    hz = terrain_hazards(Terrain(h, 16.0, 16.0), radius=0.33)
    assert hz.step[40, 40] == pytest.approx(0.2, rel=0.05)
    assert hz.roughness[40, 40] > 0.03
    assert hz.step[40, 45] == 0.0 and hz.roughness[40, 45] == 0.0  # 1 m away: outside the footprint
