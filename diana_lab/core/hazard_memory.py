"""Where the rover's own drives were stopped this episode, read back as a channel of the rover-centred window.

Why it exists: the rover's tilt guard halts a drive where the ground tilts it past the guard, and the kinematic
model (or the physics) stops a drive on a slope it cannot climb. Both report the spot (``hazard_xy``), but a
policy that sees only heights cannot tell that it has just tried there: at the wheels' scale the tilt that trips
the guard is sharper than the map's cells show. A deterministic policy backs off, sees much the same map, and
picks much the same drive again until the episode ends as stuck. The ``elevation_map`` encoding with
``hazard_radius > 0`` adds this memory as a third channel: 1 in every window cell whose centre lies within
``hazard_radius`` of a spot reported this episode, 0 elsewhere.

Numpy only: the training encoder (:mod:`diana_lab.sensing.encoders`) and the onboard runtime
(:mod:`diana_lab.deploy.encoding`) share this class, and the batched env's compiled kernel
(:func:`diana_lab.envs.batched.sensing.hazard_batch`) spells out the same arithmetic.
"""

from __future__ import annotations

import math

import numpy as np

from diana_lab.core.height_memory import window_offsets

__all__ = ["HazardMemory"]


class HazardMemory:
    """``mark`` a reported spot, ``window`` for the channel around a pose; ``reset`` per episode.

    Args:
        radius: a window cell is marked when its centre lies within this distance of a spot (m, > 0).
        cell_size, rows, cols, extent_forward, extent_side: the window's geometry (the ``elevation_map``
            encoding's).
    """

    def __init__(
        self, radius: float, cell_size: float, rows: int, cols: int, extent_forward: float, extent_side: float
    ) -> None:
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"HazardMemory: expected a positive, finite radius, got {radius}")
        self.radius = float(radius)
        self.offsets = window_offsets(cell_size, rows, cols, extent_forward, extent_side)
        self.shape = (rows, cols)
        self._spots: list[tuple[float, float]] = []

    @property
    def spots(self) -> np.ndarray:
        """``(K, 2)`` world xy of the spots marked this episode, in the order reported."""
        return np.array(self._spots, dtype=np.float64).reshape(-1, 2)

    def reset(self) -> None:
        """Forget every spot: a new episode (a new goal on a rover)."""
        self._spots.clear()

    def mark(self, xy: object) -> None:
        """Remember world ``xy`` (the first two values of a point) as a spot where a drive was stopped."""
        try:
            point = np.asarray(xy, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            point = np.zeros(0)
        if point.size < 2 or not np.isfinite(point[:2]).all():
            raise ValueError(f"HazardMemory.mark: expected a finite world (x, y), got {xy!r}")
        self._spots.append((float(point[0]), float(point[1])))

    def window(self, x: float, y: float, yaw: float) -> np.ndarray:
        """Flat ``rows * cols`` float32: 1 where a window cell round world ``(x, y)``, heading ``yaw``, lies within
        ``radius`` of a spot, else 0."""
        out = np.zeros(self.offsets.shape[0], dtype=np.float32)
        if not self._spots:
            return out
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = self.offsets[:, 0], self.offsets[:, 1]
        wx, wy = float(x) + c * dx - s * dy, float(y) + s * dx + c * dy  # the cells' centres in the world
        r2 = self.radius * self.radius
        near = np.zeros(out.shape, dtype=bool)
        for hx, hy in self._spots:
            ex, ey = wx - hx, wy - hy
            near |= ex * ex + ey * ey <= r2
        out[near] = 1.0
        return out
