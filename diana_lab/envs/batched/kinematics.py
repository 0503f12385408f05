"""The kinematic model of :mod:`diana_lab.sim.kinematic`, for many rovers in one compiled call.

:func:`execute_batch` runs one waypoint for every rover named in ``rows``, in parallel over rovers (numba
``prange``), with the rules of :class:`~diana_lab.sim.kinematic.KinematicDynamics`: the turn-then-drive path
sampled every ``sample_spacing`` metres (and every 15 degrees of turning), the pose at every sample from a plane
fitted to the terrain under the wheels, and the first sample that breaks a limit ends the waypoint (out of
bounds, the tilt guard's halt, tip-over, a slope too steep to climb, an obstacle; past a guard's trip, the
``guard_overshoot`` a driving rover carries on). The guard's back-off along
the drive or straight back, the stuck window and the reported hazard follow the scalar model step for step.

Where the scalar model builds arrays for every sample and then looks for the first failure, this walks the
samples one by one and stops at it: the same samples, the same arithmetic per sample (so the same results to
rounding: the plane fit's three sums are the one place the order of additions may differ from numpy's), and less
work. ``tests/envs/test_batched_parity.py`` holds it to the scalar model over whole episodes.

The kept trace of each rover's waypoint (what the scalar model returns as ``trace_xy``, ``trace_tilt_deg``,
``trace_rp`` and ``trace_t``) is written to ``trace[rover, k]`` as ``x, y, tilt_deg, roll, pitch, t, z``; the
statistics the env needs of it (the nearest approach to the goal, the largest tilt, roll and pitch, the time
spent over 15 degrees) are reduced here, so the env never walks the trace in Python.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from diana_lab.envs.batched.geometry import py_hypot
from diana_lab.sensing.heightfield_kernels import _jit
from diana_lab.sim.controller import TurnThenDrive
from diana_lab.sim.kinematic import KinematicDynamics

__all__ = [
    "FAILURES",
    "OUTCOME_CODES",
    "R_HALTED",
    "R_REACHED",
    "TRACE_FIELDS",
    "KinematicsArrays",
    "execute_batch",
    "trace_capacity",
]

# waypoint outcomes as codes (the order of diana_lab.sim.kinematic.FAILURE_CHECKS after "reached")
OUTCOME_CODES = ("reached", "out_of_bounds", "halted", "tipover", "stuck", "collision")
R_REACHED, R_OOB, R_HALTED, R_TIPOVER, R_STUCK, R_COLLISION = range(6)
FAILURES = (R_OOB, R_TIPOVER, R_COLLISION)  # the waypoint outcomes that end an episode (terminated)
TRACE_FIELDS = ("x", "y", "tilt_deg", "roll", "pitch", "t", "z")
TURN_SAMPLE_RAD = math.radians(15.0)  # as diana_lab.sim.kinematic
TILT_LIMIT_DEG = 15.0  # the env's time-over-15-degrees statistic
DEG = 180.0 / math.pi

# indices into the packed parameters (one float64 array each, so the kernel's signature stays short)
T_X0, T_Y0, T_DX, T_DY, T_HALF_X, T_HALF_Y = range(6)  # terrain
C_RES, C_X0, C_Y0 = range(3)  # collision clearance grid
(
    P_BASE_HEIGHT,
    P_TIPOVER_DEG,
    P_MAX_SLOPE,
    P_RADIUS,
    P_GUARD_DEG,
    P_GUARD_RETREAT,
    P_GUARD_PAUSE,
    P_RETREAT_SPEED,
    P_LENGTH,
    P_POS_TOL,
    P_HEADING_TOL,
    P_TURN_SPEED,
    P_CRUISE_SPEED,
    P_SPACING,
    P_STUCK_WINDOW,
    P_GUARD_OVERSHOOT,
) = range(16)


def trace_capacity(max_distance: float, spacing: float, retreat: float) -> int:
    """Trace rows one waypoint of at most ``max_distance`` metres can keep: the start, the turn's samples, the
    drive out and back along it (a guard halt), and a straight back-off."""
    drive = math.ceil(max_distance / spacing) + 2
    turn = math.ceil(math.pi / TURN_SAMPLE_RAD) + 1
    back = math.ceil(retreat / spacing) + 2
    return 1 + turn + 2 * drive + back + 2


@_jit(inline="always")
def _wrap(a):  # pragma: no cover (numba)
    """``diana_lab.sim.controller.wrap_angle`` of a float (Python's modulo: the divisor's sign)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@_jit(inline="always")
def _height(hs, t, x, y):  # pragma: no cover (numba)
    """``Terrain.height_at`` of one point: its triangle of the cell (clamped onto the grid), interpolated from the
    triangle's base corner as the scalar code does."""
    ny, nx = hs.shape
    gx = (x - t[T_X0]) / t[T_DX]
    gy = (y - t[T_Y0]) / t[T_DY]
    gx = min(max(gx, 0.0), nx - 1.0)
    gy = min(max(gy, 0.0), ny - 1.0)
    ix = min(int(gx), nx - 2)
    iy = min(int(gy), ny - 2)
    u = gx - ix
    v = gy - iy
    if u + v <= 1.0:
        h0 = hs[iy, ix]
        return h0 + (hs[iy, ix + 1] - h0) * u + (hs[iy + 1, ix] - h0) * v
    h0 = hs[iy + 1, ix + 1]
    return h0 + (hs[iy + 1, ix] - h0) * (1.0 - u) + (hs[iy, ix + 1] - h0) * (1.0 - v)


@_jit(inline="always")
def _pose(hs, t, wx, wy, fit, base_height, x, y, yaw):  # pragma: no cover (numba)
    """Height of the base, roll and pitch at ``(x, y, yaw)``: the plane ``z = a + b bx + c by`` fitted (least
    squares, ``fit`` the pseudo-inverse) to the terrain under the wheels (``KinematicDynamics._poses``)."""
    c, s = math.cos(yaw), math.sin(yaw)
    a = b = k = 0.0
    for w in range(wx.shape[0]):
        px = x + c * wx[w]
        px = px + s * (-wy[w])
        py = y + s * wx[w]
        py = py + c * wy[w]
        h = _height(hs, t, px, py)
        a += fit[0, w] * h
        b += fit[1, w] * h
        k += fit[2, w] * h
    norm = math.sqrt(1.0 + b * b + k * k)
    roll = math.asin(k / norm)
    pitch = -math.atan(b)
    return a + base_height * (1.0 / norm), roll, pitch


@_jit(inline="always")
def _tilt(roll, pitch):  # pragma: no cover (numba)
    return math.acos(min(max(math.cos(roll) * math.cos(pitch), -1.0), 1.0)) * DEG


@_jit(inline="always")
def _clearance(clear, cp, x, y):  # pragma: no cover (numba)
    ny, nx = clear.shape
    ix = min(max(np.int64(np.rint((x - cp[C_X0]) / cp[C_RES])), 0), nx - 1)
    iy = min(max(np.int64(np.rint((y - cp[C_Y0]) / cp[C_RES])), 0), ny - 1)
    return clear[iy, ix]


@_jit()
def _walk(
    i, tr, k0, xs, ys, yaws, times, drive_s, m, n, reverse, hs, t, clear, cp, wx, wy, fit, p, state, hazard
):  # pragma: no cover (numba)
    """``KinematicDynamics._check_path`` for rover ``i``: samples ``0..n-1`` (``xs, ys, yaws, times``; those from
    ``m`` on lie ``drive_s[j - m]`` metres along the drive) walked in order, written to ``tr[k0 + j]``, stopping
    at the first broken limit. Sets ``state[i]`` (x, y, z, roll, pitch, yaw, time) to where the rover stops and
    ``hazard[i]``; returns the outcome code, the rows kept (from ``k0``), the duration and the path length."""
    guard = p[P_GUARD_DEG]
    has_guard = not math.isnan(guard)
    has_clear = clear.shape[0] > 0
    first, code, armed = n, R_REACHED, False
    for j in range(n):
        x, y = xs[j], ys[j]
        z, roll, pitch = _pose(hs, t, wx, wy, fit, p[P_BASE_HEIGHT], x, y, yaws[j])
        tilt = _tilt(roll, pitch)
        row = tr[k0 + j]
        row[0], row[1], row[2], row[3], row[4], row[5], row[6] = x, y, tilt, roll, pitch, times[j], z
        halted = has_guard and tilt > guard
        if reverse and has_guard:  # the guard re-arms once the tilt is back under it
            armed = armed or not halted
            halted = halted and armed
        if j == 0:  # the starting sample was checked when the rover got there
            continue
        if not (abs(x) <= t[T_HALF_X] and abs(y) <= t[T_HALF_Y]):
            code = R_OOB
        elif halted:
            code = R_HALTED
        elif tilt > p[P_TIPOVER_DEG]:
            code = R_TIPOVER
        elif (pitch > p[P_MAX_SLOPE]) if reverse else (pitch < -p[P_MAX_SLOPE]):
            code = R_STUCK
        elif has_clear and _clearance(clear, cp, x, y) < p[P_RADIUS]:
            code = R_COLLISION
        if code != R_REACHED:
            first = j
            break
    if code == R_HALTED and not reverse and first >= m and p[P_GUARD_OVERSHOOT] > 0.0:
        # carried on past the trip (KinematicDynamics._carried_past_guard): the trip's sample, then further along
        reach = drive_s[first - m] + p[P_GUARD_OVERSHOOT]
        for j in range(first, n):
            if drive_s[j - m] > reach:
                break
            if j > first:
                z, roll, pitch = _pose(hs, t, wx, wy, fit, p[P_BASE_HEIGHT], xs[j], ys[j], yaws[j])
                row = tr[k0 + j]
                row[0], row[1], row[2], row[3], row[4], row[5], row[6] = (
                    xs[j],
                    ys[j],
                    _tilt(roll, pitch),
                    roll,
                    pitch,
                    times[j],
                    z,
                )
            if tr[k0 + j, 2] > p[P_TIPOVER_DEG]:
                code, first = R_TIPOVER, j
                break
    end = first if code != R_REACHED else n - 1
    if code == R_STUCK or code == R_HALTED:  # noqa: SIM109 (numba compiles comparisons, not tuple searches)
        end = max(first - 1, 0)  # the foot of the slope / the guard stops the rover before it
    kept = end + 1
    length = drive_s[end - m] if end >= m else 0.0
    duration = tr[k0 + end, 5]
    if code == R_HALTED and end >= m and not reverse:  # back along the drive, guard_retreat before the stop
        last = drive_s[end - m]
        target = last - p[P_GUARD_RETREAT]
        # the nearest sample at least guard_retreat back, or the drive's start (searchsorted(side="right") - 1
        # over [0, drive_s[0..end-m]])
        count = 1 if target >= 0.0 else 0
        for q in range(end - m + 1):
            if drive_s[q] <= target:
                count += 1
        stop = m - 1 + max(count - 1, 0)
        t_end = tr[k0 + end, 5]
        for src in range(end - 1, stop - 1, -1):
            back_s = last - (drive_s[src - m] if src >= m else 0.0)
            row = tr[k0 + kept]
            row[:] = tr[k0 + src]
            row[5] = t_end + p[P_GUARD_PAUSE] + back_s / p[P_RETREAT_SPEED]
            kept += 1
        length += length - (drive_s[stop - m] if stop >= m else 0.0)
        end = stop
        duration = tr[k0 + kept - 1, 5]
    stop_row = tr[k0 + end]  # sample ``end``, where the rover stands
    state[i, 0], state[i, 1], state[i, 2] = stop_row[0], stop_row[1], stop_row[6]
    state[i, 3], state[i, 4], state[i, 5] = stop_row[3], stop_row[4], _wrap(yaws[end])
    state[i, 6] += duration
    if code == R_STUCK:  # the wheels spin until the controller's stuck window runs out
        tr[k0 + kept - 1, 5] += p[P_STUCK_WINDOW]
        duration += p[P_STUCK_WINDOW]
        state[i, 6] += p[P_STUCK_WINDOW]
    if code == R_STUCK or code == R_HALTED:  # noqa: SIM109
        if first >= m:
            hazard[i, 0], hazard[i, 1] = xs[first], ys[first]
        else:  # while turning in place: that way is barred from here, so mark it ahead (sim.state.hazard_ahead)
            half = 0.5 * p[P_LENGTH]
            hazard[i, 0] = xs[0] + half * math.cos(yaws[n - 1])
            hazard[i, 1] = ys[0] + half * math.sin(yaws[n - 1])
    return code, kept, duration, length


@_jit(parallel=True)
def execute_batch(
    rows, state, waypoint, est, hs, t, clear, cp, wx, wy, fit, p, trace, n_trace, code, duration, length, hazard
):  # pragma: no cover (numba)
    """One waypoint for each rover ``i`` in ``rows``: ``state[i]`` = x, y, z, roll, pitch, yaw, time (updated),
    ``waypoint[i]`` (x, y), ``est[i]`` = the controller's pose estimate (x, y, yaw). Writes the kept trace
    (``trace[i, :n_trace[i]]``), the outcome ``code[i]`` (:data:`OUTCOME_CODES`), ``duration[i]`` (simulated
    seconds), ``length[i]`` (metres driven) and ``hazard[i]`` (NaN unless stuck or halted)."""
    for r in prange(rows.shape[0]):
        i = rows[r]
        tr = trace[i]
        hazard[i, 0] = hazard[i, 1] = np.nan
        x0, y0, yaw0 = state[i, 0], state[i, 1], state[i, 5]
        dx, dy = waypoint[i, 0] - est[i, 0], waypoint[i, 1] - est[i, 1]
        distance = py_hypot(dx, dy)  # the scalar model's math.hypot, to the bit
        if distance <= p[P_POS_TOL]:  # reached without moving: one sample of the current attitude
            roll, pitch = state[i, 3], state[i, 4]
            row = tr[0]
            row[0], row[1], row[2], row[3], row[4], row[5] = x0, y0, _tilt(roll, pitch), roll, pitch, 0.0
            row[6] = state[i, 2]
            n_trace[i], code[i], duration[i], length[i] = 1, R_REACHED, 0.0, 0.0
            continue
        turn = _wrap(math.atan2(dy, dx) - est[i, 2])
        if abs(turn) <= p[P_HEADING_TOL]:
            turn = 0.0  # already facing it: the controller drives straight away
        n_turn = int(math.ceil(abs(turn) / TURN_SAMPLE_RAD))
        heading = yaw0 + turn
        drive = max(distance - p[P_POS_TOL], 0.0)
        n_drive = max(int(math.ceil(drive / p[P_SPACING])), 1)
        m = 1 + n_turn
        n = m + n_drive
        xs, ys, yaws, times = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        drive_s = np.empty(n_drive)
        xs[:m], ys[:m] = x0, y0
        yaws[0], times[0] = yaw0, 0.0
        for j in range(1, m):
            yaws[j] = yaw0 + turn * j / max(n_turn, 1)
            times[j] = abs(yaws[j] - yaw0) / p[P_TURN_SPEED]
        ch, sh = math.cos(heading), math.sin(heading)
        turn_time = abs(turn) / p[P_TURN_SPEED]
        for j in range(n_drive):
            s = drive * (j + 1) / n_drive
            drive_s[j] = s
            xs[m + j] = x0 + s * ch
            ys[m + j] = y0 + s * sh
            yaws[m + j] = heading
            times[m + j] = turn_time + s / p[P_CRUISE_SPEED]
        c, kept, dur, drove = _walk(
            i, tr, 0, xs, ys, yaws, times, drive_s, m, n, False, hs, t, clear, cp, wx, wy, fit, p, state, hazard
        )
        if c == R_HALTED and drove == 0.0 and p[P_GUARD_RETREAT] > 0:
            # a halt that drove no distance: reverse guard_retreat straight behind the heading (_back_off)
            reach = p[P_GUARD_RETREAT]
            nb = max(int(math.ceil(reach / p[P_SPACING])), 1)
            bx, by, byaw = state[i, 0], state[i, 1], state[i, 5]
            cb, sb = math.cos(byaw), math.sin(byaw)
            bxs, bys, byaws, btimes = np.empty(nb + 1), np.empty(nb + 1), np.empty(nb + 1), np.empty(nb + 1)
            bdrive = np.empty(nb)
            bxs[0], bys[0], byaws[0], btimes[0] = bx, by, byaw, 0.0
            for j in range(nb):
                s = reach * (j + 1) / nb
                bdrive[j] = s
                bxs[j + 1] = bx - s * cb
                bys[j + 1] = by - s * sb
                byaws[j + 1] = byaw
                btimes[j + 1] = p[P_GUARD_PAUSE] + s / p[P_RETREAT_SPEED]
            hx, hy = hazard[i, 0], hazard[i, 1]
            # the back-off's rows follow the halt's: written from kept - 1 (its first sample, the halt's last pose,
            # overwrites that row, which is put back), then its times shifted by the halt's duration
            saved = tr[kept - 1].copy()
            bc, bkept, bdur, bdrove = _walk(
                i, tr, kept - 1, bxs, bys, byaws, btimes, bdrive, 1, nb + 1, True, hs, t, clear, cp, wx, wy, fit, p,
                state, hazard,
            )  # fmt: skip
            for k in range(kept, kept - 1 + bkept):
                tr[k, 5] += dur
            tr[kept - 1] = saved
            hazard[i, 0], hazard[i, 1] = hx, hy
            c = bc if bc == R_TIPOVER or bc == R_COLLISION or bc == R_OOB else R_HALTED  # noqa: SIM109
            kept, dur, drove = kept - 1 + bkept, dur + bdur, bdrove
        n_trace[i], code[i], duration[i], length[i] = kept, c, dur, drove


class KinematicsArrays:
    """The packed, read-only inputs of :func:`execute_batch` for one world, robot and ``dynamics`` config.

    Built from the scalar model (:class:`~diana_lab.sim.kinematic.KinematicDynamics`) so that both read the
    same wheel layout, plane fit and collision clearance.
    """

    def __init__(self, dynamics: KinematicDynamics, controller: TurnThenDrive) -> None:
        world, robot, cfg = dynamics.world, dynamics.robot, dynamics.cfg
        terrain = world.terrain
        self.heights = np.ascontiguousarray(terrain.heights, dtype=np.float64)
        self.terrain = np.array(
            [terrain.x_min, terrain.y_min, terrain.dx, terrain.dy, terrain.size_x / 2.0, terrain.size_y / 2.0]
        )
        clearance = dynamics._collision_clearance
        if clearance is None:
            self.clearance, self.clearance_grid = np.zeros((0, 0)), np.zeros(3)
        else:
            grid, res, x0, y0 = clearance
            self.clearance = np.ascontiguousarray(grid, dtype=np.float64)
            self.clearance_grid = np.array([res, x0, y0], dtype=np.float64)
        self.wheel_x = np.ascontiguousarray(dynamics._wheels[:, 0])
        self.wheel_y = np.ascontiguousarray(dynamics._wheels[:, 1])
        self.fit = np.ascontiguousarray(dynamics._fit)
        guard = math.nan if robot.tilt_guard_deg is None else float(robot.tilt_guard_deg)
        self.params = np.array(
            [
                robot.base_height,
                robot.tipover_deg,
                math.radians(robot.max_slope_deg),
                robot.radius,
                guard,
                robot.guard_retreat,
                robot.guard_pause_s,
                robot.retreat_speed,
                robot.length,
                controller.position_tolerance,
                controller.heading_tolerance,
                controller.turn_speed,
                controller.cruise_speed,
                cfg.sample_spacing,
                cfg.stuck_window_s,
                cfg.guard_overshoot,
            ],
            dtype=np.float64,
        )
        self.spacing, self.retreat = float(cfg.sample_spacing), float(robot.guard_retreat)

    def capacity(self, max_distance: float) -> int:
        """Trace rows a waypoint ``max_distance`` metres from the rover's estimate may keep."""
        return trace_capacity(max_distance, self.spacing, self.retreat)

    def execute(
        self,
        rows: np.ndarray,
        state: np.ndarray,
        waypoint: np.ndarray,
        est: np.ndarray,
        trace: np.ndarray,
        n_trace: np.ndarray,
        code: np.ndarray,
        duration: np.ndarray,
        length: np.ndarray,
        hazard: np.ndarray,
    ) -> None:
        """:func:`execute_batch` with this world's arrays."""
        execute_batch(
            rows,
            state,
            waypoint,
            est,
            self.heights,
            self.terrain,
            self.clearance,
            self.clearance_grid,
            self.wheel_x,
            self.wheel_y,
            self.fit,
            self.params,
            trace,
            n_trace,
            code,
            duration,
            length,
            hazard,
        )
