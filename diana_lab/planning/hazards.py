"""Terrain hazard layers at the rover's footprint scale, GESTALT / ENav style.

For every terrain sample we fit a least-squares plane to the heights under a disc the size of the rover
footprint (the circumscribed radius, so the answer does not depend on the heading the rover will have):

* **slope** -- the tilt of that plane. It is what the chassis feels (the wheels rest on the plane through the
  contact points), which per-sample gradients over- or under-state on a 0.2 m DEM.
* **step** -- the largest height difference between two neighbouring samples inside the footprint *after
  removing the plane's own rise*. Raw neighbour differences would flag every ordinary slope as a step (on the
  Mars yard a 25 degree slope already rises 9 cm between samples); de-tilted they measure what a wheel meets
  as an edge (rock sides, rims, ditch walls).
* **roughness** -- the RMS residual of the plane fit: how far the ground departs from the plane the body rides
  on; a proxy for belly strikes and wheel unloading.

All three are computed with ``scipy.ndimage`` correlations/rank filters over the footprint (no Python loops
over cells), so a 257 x 257 DEM takes milliseconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from diana_lab.sim.terrain import Terrain

__all__ = ["HazardLayers", "footprint_mask", "terrain_hazards"]

# the four "forward" neighbour directions (diy, dix); the other four are the same pairs seen from the far end
_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


@dataclass(frozen=True)
class HazardLayers:
    """Per-sample hazards on the terrain grid (``[iy, ix]``): slope in degrees, step and roughness in m."""

    slope_deg: np.ndarray
    step: np.ndarray
    roughness: np.ndarray


def footprint_mask(radius: float, dx: float, dy: float) -> np.ndarray:
    """Boolean disc of samples that shape the surface under a rover of ``radius`` centred on a sample.

    The disc radius is the footprint radius plus half a grid spacing: the piecewise-linear surface under the
    footprint edge depends on the samples just outside it. It always contains the 8 neighbours, so that the
    plane fit is well posed even for a rover smaller than one cell.
    """
    reach = max(radius + 0.5 * max(dx, dy), float(np.hypot(dx, dy)) + 1e-9)
    kx, ky = int(np.floor(reach / dx)), int(np.floor(reach / dy))
    oy, ox = np.mgrid[-ky : ky + 1, -kx : kx + 1]
    return np.hypot(ox * dx, oy * dy) <= reach


def terrain_hazards(terrain: Terrain, radius: float) -> HazardLayers:
    """Slope, step and roughness of every terrain sample for a footprint of ``radius`` metres.

    The plane fit uses the symmetry of the disc: with offsets centred on the sample, ``sum(x) = sum(y) =
    sum(xy) = 0``, so the plane ``z = c + a x + b y`` decouples into ``c = mean(z)``,
    ``a = sum(xz)/sum(x^2)``, ``b = sum(yz)/sum(y^2)``; each is one correlation. The RMS residual follows
    from the same moments (``var(z) - a^2 mean(x^2) - b^2 mean(y^2)``) because the fitted components are
    orthogonal.
    Beyond the grid edge the heights are extended by odd reflection (``2 h[0] - h[k]``), which continues
    the edge slope, so a plane stays a plane up to the edge instead of growing a fake kink.
    """
    dx, dy = terrain.dx, terrain.dy
    fp = footprint_mask(radius, dx, dy)
    ky, kx = fp.shape[0] // 2, fp.shape[1] // 2
    pad = ((ky + 1, ky + 1), (kx + 1, kx + 1))
    h = np.pad(terrain.heights, pad, mode="reflect", reflect_type="odd")
    crop = (slice(ky + 1, h.shape[0] - ky - 1), slice(kx + 1, h.shape[1] - kx - 1))
    oy, ox = np.mgrid[-ky : ky + 1, -kx : kx + 1]
    xs, ys = np.where(fp, ox * dx, 0.0), np.where(fp, oy * dy, 0.0)
    n = float(fp.sum())
    sxx, syy = float((xs**2).sum()), float((ys**2).sum())

    # plane gradient (correlate: out[i] = sum_k w[k] h[i + k - centre])
    a = ndi.correlate(h, xs / sxx, mode="nearest")
    b = ndi.correlate(h, ys / syy, mode="nearest")
    slope_deg = np.degrees(np.arctan(np.hypot(a, b)))
    explained = a**2 * (sxx / n) + b**2 * (syy / n)
    roughness = np.sqrt(np.maximum(_window_variance(h, fp / n) - explained, 0.0))

    # step: max over neighbour pairs (p, p + d) in the footprint of |h[p+d] - h[p] - plane rise along d|
    step = np.zeros_like(h)
    for diy, dix in _DIRECTIONS:
        diff = _neighbour_difference(h, diy, dix)
        rise = a * (dix * dx) + b * (diy * dy)
        pairs = _pair_footprint(fp, diy, dix)
        hi = ndi.maximum_filter(diff, footprint=pairs, mode="nearest")
        lo = ndi.minimum_filter(diff, footprint=pairs, mode="nearest")
        step = np.maximum(step, np.maximum(hi - rise, rise - lo))
    return HazardLayers(slope_deg=slope_deg[crop], step=step[crop], roughness=roughness[crop])


def _window_variance(h: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Variance of the heights in the footprint window around every sample.

    Heights are shifted by their mean first so that ``E[z^2] - E[z]^2`` keeps its precision on tall terrain.
    """
    hc = h - float(h.mean())
    m1 = ndi.correlate(hc, weights, mode="nearest")
    return ndi.correlate(hc * hc, weights, mode="nearest") - m1 * m1


def _pair_footprint(fp: np.ndarray, diy: int, dix: int) -> np.ndarray:
    """Offsets ``k`` of the footprint whose neighbour ``k + (diy, dix)`` is in the footprint too."""
    ky, kx = fp.shape
    shifted = np.zeros_like(fp)
    ys, xs = slice(max(-diy, 0), ky - max(diy, 0)), slice(max(-dix, 0), kx - max(dix, 0))
    shifted[ys, xs] = fp[ys.start + diy : ys.stop + diy, xs.start + dix : xs.stop + dix]
    return fp & shifted


def _neighbour_difference(h: np.ndarray, diy: int, dix: int) -> np.ndarray:
    """``h[iy + diy, ix + dix] - h[iy, ix]``; where the neighbour falls off the grid, the nearest valid value.

    Repeating the nearest difference (rather than 0) keeps the grid edge from looking like a step on a slope.
    """
    ny, nx = h.shape
    x0, x1 = max(0, -dix), nx - max(0, dix)
    valid = h[diy:ny, x0 + dix : x1 + dix] - h[0 : ny - diy, x0:x1]
    pad = ((0, diy), (x0, nx - x1))
    return np.pad(valid, pad, mode="edge")
