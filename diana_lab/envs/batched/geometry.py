"""The env's small geometry for many rovers, compiled, with the scalar env's own rounding.

Why compiled rather than numpy: the scalar env computes distances with Python's ``math.hypot`` (CPython's own
algorithm, which differs from the C library's ``hypot``, numpy's, in the last bit now and then) and angles with
the C library's ``sin``/``cos``/``atan2`` (which numpy's vectorised loops may not call). A
last bit matters where a value meets a threshold: the kinematic model samples a drive every 0.1 m, and a
discrete action space's waypoints lie exactly 1, 2 or 3 m away, so ``ceil(2.8 / 0.1)`` is decided by it. Here
:func:`py_hypot` is CPython's algorithm and numba's ``math`` functions are the C library's, so the batched env
makes the scalar env's decisions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from diana_lab.sensing.heightfield_kernels import _jit

__all__ = ["goal_vectors", "moved", "place_waypoints", "py_hypot"]

_SPLIT = 134217729.0  # 2**27 + 1: Dekker's split of a double into two halves


@_jit(inline="always")
def _mul(x, y):  # pragma: no cover (numba)
    """``x * y`` as an unevaluated sum ``hi + lo`` (exact; Dekker's product)."""
    cx = _SPLIT * x
    hx = cx - (cx - x)
    lx = x - hx
    cy = _SPLIT * y
    hy = cy - (cy - y)
    ly = y - hy
    p = x * y
    return p, ((hx * hy - p) + hx * ly + lx * hy) + lx * ly


@_jit(inline="always")
def py_hypot(a, b):  # pragma: no cover (numba)
    """``math.hypot(a, b)`` as CPython computes it (``vector_norm`` in ``mathmodule.c``: a scaled, compensated sum
    of squares and one Newton correction of the square root); equal to it bit for bit."""
    a, b = abs(a), abs(b)
    top = max(a, b)
    if math.isnan(a) or math.isnan(b):
        return math.inf if math.isinf(top) else math.nan
    if top == 0.0 or math.isinf(top):
        return top
    _, e = math.frexp(top)
    scale = math.ldexp(1.0, -e)
    csum, frac1, frac2 = 1.0, 0.0, 0.0
    for x in (a * scale, b * scale):
        hi, lo = _mul(x, x)
        s = csum + hi
        frac2 += (csum - s) + hi
        csum = s
        frac1 += lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    hi, lo = _mul(-h, h)
    s = csum + hi
    frac2 += (csum - s) + hi
    csum = s
    frac1 += lo
    h += (csum - 1.0 + (frac1 + frac2)) / (2.0 * h)
    return h / scale


@_jit(inline="always")
def _wrap(a):  # pragma: no cover (numba)
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@_jit(parallel=True)
def place_waypoints(ox, oy, est, rover_frame, box, out):  # pragma: no cover (numba)
    """``RoverNavEnv``'s waypoints: the action frame's offsets ``(ox, oy)`` turned by each rover's estimated yaw
    (``rover_frame``), added to its estimated position ``est[i]`` (x, y, yaw, ...) and clamped into ``box[i]``
    (x0, x1, y0, y1: its map less the margin)."""
    for i in prange(out.shape[0]):
        x, y = ox[i], oy[i]
        if rover_frame:
            c, s = math.cos(est[i, 2]), math.sin(est[i, 2])
            x, y = c * x - s * y, s * x + c * y
        out[i, 0] = min(max(est[i, 0] + x, box[i, 0]), box[i, 1])
        out[i, 1] = min(max(est[i, 1] + y, box[i, 2]), box[i, 3])


@_jit(parallel=True)
def goal_vectors(rows, est, goal, scale, low, high, out, distance, error):  # pragma: no cover (numba)
    """``RoverNavEnv._goal_vector`` of each rover in ``rows``: ``est[i]`` = x, y, yaw, roll, pitch; ``low[i]`` and
    ``high[i]`` its world's bounds. Writes ``out[i]`` (float32), ``distance[i]`` and ``error[i]``."""
    half_pi = math.pi / 2
    for r in prange(rows.shape[0]):
        i = rows[r]
        dx, dy = goal[i, 0] - est[i, 0], goal[i, 1] - est[i, 1]
        d = py_hypot(dx, dy)
        e = _wrap(math.atan2(dy, dx) - est[i, 2])
        g = (d / scale, math.sin(e), math.cos(e), est[i, 3] / half_pi, est[i, 4] / half_pi)
        for k in range(5):
            out[i, k] = np.float32(min(max(g[k], low[i, k]), high[i, k]))
        out[i, 5] = np.float32(min(max(math.sin(est[i, 2]), low[i, 5]), high[i, 5]))
        out[i, 6] = np.float32(min(max(math.cos(est[i, 2]), low[i, 6]), high[i, 6]))
        distance[i], error[i] = d, e


@_jit()
def moved(old, new):  # pragma: no cover (numba)
    """``math.dist`` of each row of ``old`` and ``new`` ``(n, 2)``."""
    out = np.empty(old.shape[0])
    for i in range(old.shape[0]):
        out[i] = py_hypot(old[i, 0] - new[i, 0], old[i, 1] - new[i, 1])
    return out
