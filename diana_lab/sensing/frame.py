"""One sensor reading: the range image, and the point cloud and depth image derived from it on demand.

The point cloud is computed lazily (``functools.cached_property``), in one compiled pass over the rays, unless
the caster already wrote it while casting (the heightfield caster without noise does: it costs ~1 ns a ray
there); every frame can give it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from diana_lab.core.rotations import rpy_matrix

__all__ = ["SensorFrame"]


@dataclass(eq=False)
class SensorFrame:
    """A frame taken at rover pose ``position``/``rpy``.

    ``ranges[i, j]`` is the distance (m) from the sensor to the first surface along ray ``(i, j)``, or NaN
    where the ray returned nothing usable (no hit, beyond ``max_range``, closer than ``min_range``, or
    dropped by the noise model); there is never a fake return at the maximum range.
    """

    ranges: np.ndarray  # (H, W) float32
    position: np.ndarray  # (3,) rover base position in the world when the frame was taken
    rpy: np.ndarray  # (3,) rover roll, pitch, yaw (rad)
    directions: np.ndarray  # (H*W, 3) unit ray directions in the rover frame (shared by all frames)
    origin: np.ndarray  # (3,) sensor position in the rover frame (the mount)
    axis_cos: np.ndarray | None = None  # (H, W) cosine between each ray and the optical axis (cameras)
    cloud: np.ndarray | None = field(default=None, repr=False)  # ``points``, when the caster wrote it already

    @property
    def shape(self) -> tuple[int, int]:
        return self.ranges.shape

    @cached_property
    def valid(self) -> np.ndarray:
        """``(H, W)`` bool: rays with a return."""
        return ~np.isnan(self.ranges)

    @cached_property
    def points(self) -> np.ndarray:
        """``(N, 3)`` float32 returns in the ROVER frame (x forward, y left, z up), valid rays only, in
        row-major pixel order: ``directions * range + origin`` in float32."""
        if self.cloud is not None:
            return self.cloud
        from diana_lab.sensing.returns import valid_points  # numba: imported on first use

        f32 = np.float32
        return valid_points(
            np.ascontiguousarray(self.ranges.reshape(-1), dtype=f32),  # no copies for a sensor's own frame
            np.ascontiguousarray(self.directions, dtype=f32),
            np.asarray(self.origin, dtype=f32),
        )

    @cached_property
    def depth(self) -> np.ndarray | None:
        """``(H, W)`` float32 depth along the optical axis (what a depth camera reports), NaN without a
        return; ``None`` for sensors without an optical axis (a spinning lidar)."""
        if self.axis_cos is None:
            return None
        return self.ranges * self.axis_cos

    def points_world(self) -> np.ndarray:
        """The valid returns in the world frame, ``(N, 3)`` float64 (for plots and checks)."""
        return self.points @ rpy_matrix(self.rpy).T + np.asarray(self.position, dtype=np.float64)
