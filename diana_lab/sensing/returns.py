"""A frame's returns as a point cloud in the rover frame, in one compiled pass (numba, one thread).

Why: the numpy form (``directions.take(valid) * ranges.take(valid)[:, None] + origin``) makes five
temporaries and costs ~60 us for a 64 x 48 frame, a fifth of the whole cast; one loop over the rays writes
the same float32 points (the same two roundings: the product, then the sum) in ~5 us.
"""

from __future__ import annotations

import numpy as np

from diana_lab.sensing.heightfield_kernels import _jit

__all__ = ["valid_points"]


@_jit()
def valid_points(ranges, directions, origin):  # pragma: no cover (numba)
    """``(M, 3)`` float32 points ``directions[i] * ranges[i] + origin`` of the rays with a return (range not
    NaN), in ray order. ``ranges (N,)`` and ``directions (N, 3)`` float32 (C-contiguous), ``origin (3,)``
    float32; float32 arithmetic throughout, rounded as numpy rounds it.

    Branch-free: every ray is written to the next free row, which only a return advances (returns and
    dropouts interleave at random in a noisy frame, and a branch per ray would be mispredicted half the
    time). The result is a view of the first ``M`` rows of an ``(N, 3)`` buffer."""
    n = ranges.shape[0]
    out = np.empty((n, 3), dtype=np.float32)
    ox, oy, oz = origin[0], origin[1], origin[2]
    j = 0
    for i in range(n):
        r = ranges[i]
        out[j, 0] = np.float32(directions[i, 0] * r) + ox
        out[j, 1] = np.float32(directions[i, 1] * r) + oy
        out[j, 2] = np.float32(directions[i, 2] * r) + oz
        j += not np.isnan(r)
    return out[:j]
