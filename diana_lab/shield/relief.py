"""Relief a wheel feels: the slope, steps and roughness under the rover's footprint, judged on a height map.

Why it exists: in physics the reference policy's rover tips over on ground the kinematic model and the slope
shield's tilt check call drivable, where relief a cell or two wide (a step, a rough patch, a short steep face)
rolls it. The A* oracle keeps off the cells its cost map calls lethal (:mod:`diana_lab.planning.costmap`) and
reaches 0.96 in physics. This module judges the same three things on the rover's own map, so that the shield
can keep drives off such cells (``eval.shield.relief``): for every cell, a least-squares plane through the known
cells of the footprint centred on it (the cells within ``footprint_radius``, 13 at 0.2 m) gives

* ``slope``: the plane's steepest slope, over ``slope_deg`` (the cost map's lethal slope: the robot's
  ``max_slope_deg`` less its 3 deg margin, 22 deg for the Jackal);
* ``step``: the largest height change between two neighbouring footprint cells once the plane's own rise
  between them is taken off (de-tilted), over ``step``;
* ``roughness``: the RMS of the cells about the plane, over ``roughness``.

A cell is judged only when its own height and at least ``min_known`` of its footprint's cells are known: next
to unseen ground there is no footprint to fit. Unjudged cells are not hazards (as unseen ground passes the tilt
check); :func:`relief_judgement` also says which cells were judged, for a shield that keeps off unjudged ground
too. The map should hold each cell's *mean* return (``HeightMemory(mean=True)``): a dense sensor puts many
returns in a cell, whose highest stands above the ground on any slope and reads as steps and roughness.

Numpy only, like the shield: the onboard runtime shares it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ReliefLimits", "footprint_cells", "relief_hazards", "relief_judgement"]

# neighbouring-cell directions the step is measured along (each pair once): right, up, and both diagonals
_STEP_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


@dataclass(frozen=True)
class ReliefLimits:
    """What makes a cell a hazard; see the module docstring. ``footprint_radius`` in m, ``step`` and
    ``roughness`` in m (roughness RMS)."""

    slope_deg: float
    step: float
    roughness: float
    footprint_radius: float
    min_known: int

    def __post_init__(self) -> None:
        if not (0.0 < self.slope_deg < 90.0 and self.step > 0 and self.roughness > 0 and self.footprint_radius > 0):
            raise ValueError(
                "ReliefLimits: expected 0 < slope_deg < 90 and a positive step, roughness and footprint_radius, "
                f"got {self}"
            )
        if not (isinstance(self.min_known, int) and self.min_known >= 3):
            raise ValueError(
                f"ReliefLimits: expected min_known an integer >= 3 (a plane needs 3), got {self.min_known}"
            )


def footprint_cells(cell_size: float, radius: float) -> list[tuple[int, int]]:
    """The ``(dy, dx)`` cell offsets whose centres lie within ``radius`` (m) of a cell's centre."""
    k = int(radius / cell_size)
    return [
        (dy, dx)
        for dy in range(-k, k + 1)
        for dx in range(-k, k + 1)
        if math.hypot(dx * cell_size, dy * cell_size) <= radius + 1e-9
    ]


def relief_hazards(
    grid: np.ndarray, box: tuple[int, int, int, int], cell_size: float, limits: ReliefLimits
) -> np.ndarray:
    """Whether each cell of ``grid`` (``(N, M)`` heights in m, NaN unknown, indexed ``[iy, ix]``) inside ``box``
    (``ix0, iy0, ix1, iy1``, end-exclusive) is a relief hazard, ``(iy1 - iy0, ix1 - ix0)`` bool."""
    return relief_judgement(grid, box, cell_size, limits)[0]


def relief_judgement(
    grid: np.ndarray, box: tuple[int, int, int, int], cell_size: float, limits: ReliefLimits
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`relief_hazards` and whether each cell was judged at all (its own height and ``min_known`` of its
    footprint's cells known), both ``(iy1 - iy0, ix1 - ix0)`` bool.

    All cells at once: one shifted view of the (padded) grid per footprint cell, and the plane fit's sums over
    them. Heights are taken relative to the centre cell, so that float32 maps of high ground keep their
    precision."""
    ix0, iy0, ix1, iy1 = box
    ny, nx = iy1 - iy0, ix1 - ix0
    if ny <= 0 or nx <= 0:
        empty = np.zeros((max(ny, 0), max(nx, 0)), dtype=bool)
        return empty, empty.copy()
    offsets = footprint_cells(cell_size, limits.footprint_radius)
    k = max(max(abs(dy), abs(dx)) for dy, dx in offsets)
    rows, cols = grid.shape
    pad = np.full((ny + 2 * k, nx + 2 * k), np.nan)
    sy0, sy1, sx0, sx1 = max(iy0 - k, 0), min(iy1 + k, rows), max(ix0 - k, 0), min(ix1 + k, cols)
    if sy0 < sy1 and sx0 < sx1:
        pad[sy0 - iy0 + k : sy1 - iy0 + k, sx0 - ix0 + k : sx1 - ix0 + k] = grid[sy0:sy1, sx0:sx1]
    centre = pad[k : k + ny, k : k + nx]
    base = np.nan_to_num(centre)

    def rel(dy: int, dx: int) -> np.ndarray:
        return pad[k + dy : k + dy + ny, k + dx : k + dx + nx] - base

    sums = dict.fromkeys(("n", "x", "y", "xx", "xy", "yy", "z", "xz", "yz", "zz"), 0.0)
    heights: dict[tuple[int, int], np.ndarray] = {}
    for dy, dx in offsets:
        z = rel(dy, dx)
        heights[(dy, dx)] = z
        known = np.isfinite(z)
        zk = np.where(known, z, 0.0)
        x, y = dx * cell_size, dy * cell_size
        sums["n"] = sums["n"] + known
        sums["x"] = sums["x"] + known * x
        sums["y"] = sums["y"] + known * y
        sums["xx"] = sums["xx"] + known * (x * x)
        sums["xy"] = sums["xy"] + known * (x * y)
        sums["yy"] = sums["yy"] + known * (y * y)
        sums["z"] = sums["z"] + zk
        sums["xz"] = sums["xz"] + zk * x
        sums["yz"] = sums["yz"] + zk * y
        sums["zz"] = sums["zz"] + zk * zk
    count = np.maximum(sums["n"], 1)
    mx, my, mz = sums["x"] / count, sums["y"] / count, sums["z"] / count
    cxx, cxy, cyy = sums["xx"] / count - mx * mx, sums["xy"] / count - mx * my, sums["yy"] / count - my * my
    cxz, cyz, czz = sums["xz"] / count - mx * mz, sums["yz"] / count - my * mz, sums["zz"] / count - mz * mz
    det = cxx * cyy - cxy * cxy
    judged = (sums["n"] >= limits.min_known) & (det > 1e-12) & np.isfinite(centre)
    det = np.where(judged, det, 1.0)
    a = (cyy * cxz - cxy * cyz) / det  # the plane's rise per metre along x
    b = (cxx * cyz - cxy * cxz) / det  # and along y
    hazard = np.hypot(a, b) > math.tan(math.radians(limits.slope_deg))
    residual = np.maximum(czz - (a * cxz + b * cyz), 0.0)  # mean squared departure from the plane
    hazard |= np.sqrt(residual) > limits.roughness
    step = np.zeros((ny, nx))
    for dy, dx in offsets:
        for ddy, ddx in _STEP_DIRECTIONS:
            if (dy + ddy, dx + ddx) in heights:
                rise = (a * ddx + b * ddy) * cell_size
                jump = np.abs(heights[(dy + ddy, dx + ddx)] - heights[(dy, dx)] - rise)
                step = np.fmax(step, jump)  # fmax: an unknown pair (NaN) leaves the step as it was
    hazard |= step > limits.step
    return hazard & judged, judged
