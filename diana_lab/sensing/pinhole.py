"""A pinhole camera's pixel grid, as the ray caster's near-field raster needs it (no numba here: cheap to import)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["CHECK_TOL", "Pinhole"]

CHECK_TOL = 1e-3  # pixels: how far a camera's ray may project from its pixel centre for the model to hold


@dataclass(frozen=True, eq=False)
class Pinhole:
    """A pinhole camera's pixel grid: ray ``row * width + col`` points through the centre of pixel ``(row, col)``
    of an image plane spanning ``tan_half_h`` / ``tan_half_v`` either side of the optical axis (sensor +x; columns
    grow to -y, rows to -z, as :func:`diana_lab.sensing.camera.pinhole_pattern` lays them out), turned into the
    rover frame by ``mount_rotation``. All the raster needs to find the pixels a terrain cell can cover."""

    width: int
    height: int
    tan_half_h: float
    tan_half_v: float
    mount_rotation: np.ndarray  # (3, 3): sensor frame -> rover frame
    params: np.ndarray = field(
        init=False, repr=False
    )  # [width, height, tan_half_h, tan_half_v], as the kernel takes them

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"Pinhole: expected a positive image size, got {self.width} x {self.height}")
        if not (0.0 < self.tan_half_h < math.inf and 0.0 < self.tan_half_v < math.inf):
            raise ValueError(
                f"Pinhole: expected positive finite half-angle tangents, got {self.tan_half_h}, {self.tan_half_v}"
            )
        m = np.asarray(self.mount_rotation, dtype=np.float64)
        if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-9):
            raise ValueError(f"Pinhole: mount_rotation must be a 3 x 3 rotation matrix, got {m.tolist()}")
        object.__setattr__(self, "mount_rotation", np.ascontiguousarray(m))
        params = np.array([self.width, self.height, self.tan_half_h, self.tan_half_v], dtype=np.float64)
        object.__setattr__(self, "params", params)

    def pixels(self, directions: np.ndarray) -> np.ndarray:
        """``(N, 2)`` (column, row) image coordinates of rover-frame ``directions (N, 3)`` (NaN behind the camera)."""
        s = np.asarray(directions, dtype=np.float64) @ self.mount_rotation  # rows: sensor-frame directions
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(s[:, 0] > 0.0, 1.0 / s[:, 0], np.nan)
        col = (-s[:, 1] * inv / self.tan_half_h + 1.0) * 0.5 * self.width - 0.5
        row = (-s[:, 2] * inv / self.tan_half_v + 1.0) * 0.5 * self.height - 0.5
        return np.column_stack([col, row])

    def check(self, directions: np.ndarray) -> None:
        """Raise ``ValueError`` unless ``directions`` are this camera's rays, pixel by pixel in row-major order:
        the raster would otherwise test the wrong pixels and return wrong ranges without a sign."""
        n = self.width * self.height
        if len(directions) != n:
            raise ValueError(f"Pinhole: {len(directions)} ray directions for a {self.width} x {self.height} image")
        rows, cols = np.divmod(np.arange(n), self.width)
        off = np.abs(self.pixels(directions) - np.column_stack([cols, rows]))
        worst = float(np.nanmax(off)) if np.all(np.isfinite(off)) else math.inf
        if worst > CHECK_TOL:
            raise ValueError(
                f"Pinhole: the ray directions are not this camera's pixel rays (a ray projects {worst:.3g} pixels "
                f"from its pixel centre; tolerance {CHECK_TOL})"
            )
