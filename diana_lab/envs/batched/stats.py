"""What the env needs of each rover's waypoint trace, reduced in one compiled pass (no Python loop per rover)."""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from diana_lab.envs.batched.kinematics import TILT_LIMIT_DEG
from diana_lab.sensing.heightfield_kernels import _jit

__all__ = ["STATS", "trace_stats"]

STATS = ("nearest_goal_m", "max_tilt_deg", "max_abs_roll", "max_abs_pitch", "time_over_15deg_s")


@_jit(parallel=True)
def trace_stats(trace, n_trace, goal):  # pragma: no cover (numba)
    """``(n, 5)``: per rover, over its kept trace (rows ``x, y, tilt_deg, roll, pitch, t, ...``), the nearest
    approach to ``goal[i]`` (the env's success test), the largest tilt, ``|roll|`` and ``|pitch|`` (the tilt
    reward terms), and the seconds spent over 15 degrees of tilt when the largest tilt passed them
    (``WaypointResult.sample_durations``: each sample stands for the time since the one before it)."""
    n = trace.shape[0]
    out = np.empty((n, 5))
    for i in prange(n):
        k = n_trace[i]
        gx, gy = goal[i, 0], goal[i, 1]
        nearest, tilt, roll, pitch, over = np.inf, -np.inf, -np.inf, -np.inf, 0.0
        prev_t = 0.0
        for j in range(k):
            row = trace[i, j]
            nearest = min(nearest, math.hypot(row[0] - gx, row[1] - gy))
            tilt = max(tilt, row[2])
            roll = max(roll, abs(row[3]))
            pitch = max(pitch, abs(row[4]))
            if row[2] > TILT_LIMIT_DEG:
                over += max(row[5] - prev_t, 0.0) if j > 0 else row[5]
            prev_t = row[5]
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = nearest, tilt, roll, pitch
        out[i, 4] = over if tilt > TILT_LIMIT_DEG else 0.0
    return out
