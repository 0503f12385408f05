"""Kinematic dynamics: the rover follows the controller's ideal path exactly; the terrain sets its pose.

This is the fast mode for training. The turn-then-drive path is computed analytically, then sampled every
``cfg.sample_spacing`` metres (and every 15 degrees of turning); at every sample the rover's height, roll and
pitch come from a least-squares plane through the terrain under its wheels (one vectorised solve for all
samples). The first sample that violates a limit ends the waypoint:

* ``tipover``: tilt above ``robot.tipover_deg``;
* ``stuck``: nose-up pitch above ``robot.max_slope_deg`` (the wheels cannot climb it);
* ``collision``: an obstacle taller than ``robot.ground_clearance`` within ``robot.radius`` of the centre;
* ``out_of_bounds``: the centre leaves the terrain;
* ``halted`` (with ``robot.tilt_guard_deg``, the rover's tilt fault protection): the tilt passes the guard
  (below the tip-over limit). The rover stops at the sample before, stands still ``robot.guard_pause_s``
  seconds and backs ``robot.guard_retreat`` metres along its own track at ``robot.retreat_speed`` (the pause
  and the speed count in time only: this model has no body to settle); the trace holds the drive out and back.
  A halt before the drive began (while turning in place) backs it the same distance straight behind its
  heading: standing still, the next turn on the same steep spot trips the guard again, and a rover that never
  leaves it waits out the episode. In both modes the guard re-arms during a back-off once the tilt is back
  under it, and stops the back-off where it passes again; a slope too steep to climb backwards stops it too,
  and ``tipover``, ``collision`` or ``out_of_bounds`` end the waypoint as themselves.
  ``cfg.guard_overshoot`` (metres, 0 by default) calibrates the guard against a body with momentum: a driving
  rover carries on that far past the trip before it stops, and a tilt over the tip-over limit there (the trip's
  own sample included) is a ``tipover``. PyBullet's rover, driven to the same waypoints, tips
  over where the guard trips and the ground steepens just beyond (``python -m diana_lab.calibrate``).

``stuck`` and ``halted`` report where the wheels met the ground they could not drive (``hazard_xy``; while
turning in place, half a rover length towards the heading it was turning to).

PyBullet is used only for rendering, through the same scene as the physics mode, built lazily.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cached_property

import numpy as np

from diana_lab.config.sim import KinematicConfig, RobotConfig
from diana_lab.sim.controller import TurnThenDrive, wrap_angle
from diana_lab.sim.state import RoverState, WaypointResult, hazard_ahead, tilt_deg
from diana_lab.sim.world import World

PoseEstimate = Callable[[RoverState], tuple[np.ndarray, float]]
TURN_SAMPLE_RAD = math.radians(15.0)
# on one sample, the first listed wins. ``halted`` comes before the rest: the tilt is continuous along the path,
# so a guard watching it (a rover's IMU, many times a sample) trips where it crosses the guard, short of the sample
FAILURE_CHECKS = ("out_of_bounds", "halted", "tipover", "stuck", "collision")


class KinematicDynamics:
    """Exact path following with terrain-conforming pose; see the module docstring for the rules."""

    def __init__(self, cfg: KinematicConfig, world: World, robot: RobotConfig) -> None:
        self.cfg, self.world, self.robot = cfg, world, robot
        half = robot.track_width / 2.0
        self._wheels = np.array([(ax, side) for ax in robot.axle_x for side in (half, -half)])  # body frame
        self._wheel_x = self._wheels[:, :1].copy()  # (W, 1)
        self._wheel_y_signed = np.stack([-self._wheels[:, 1:], self._wheels[:, 1:]])  # (2, W, 1): -by, by
        design = np.column_stack([np.ones(len(self._wheels)), self._wheels])
        self._fit = np.linalg.pinv(design)  # (3, W): plane coefficients (a, b, c) of z = a + b*bx + c*by
        self._max_slope_rad = math.radians(robot.max_slope_deg)
        self._state = RoverState()
        self._scene = None

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> RoverState:
        return self._state

    @cached_property
    def _collision_clearance(self) -> tuple[np.ndarray, float, float, float] | None:
        """Distance to the nearest obstacle cell the chassis cannot pass over; ``None`` without such cells."""
        from scipy.ndimage import distance_transform_edt

        om = self.world.obstacle_map
        blocking = om.height > self.robot.ground_clearance
        if not blocking.any():
            return None
        clearance = distance_transform_edt(~blocking) * om.resolution
        return clearance, om.resolution, om.x_min, om.y_min

    def _clearance_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Clearance at each sample (inf in a world with nothing the chassis could hit)."""
        if self._collision_clearance is None:
            return np.full(np.shape(x), np.inf)
        clearance, res, x0, y0 = self._collision_clearance
        ny, nx = clearance.shape
        ix = np.minimum(np.maximum(np.rint((x - x0) / res).astype(np.int64), 0), nx - 1)
        iy = np.minimum(np.maximum(np.rint((y - y0) / res).astype(np.int64), 0), ny - 1)
        return clearance[iy, ix]

    def _poses(self, xy: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Height of the base ``(K,)`` and roll, pitch ``(K, 2)`` at samples ``xy (K, 2)``, ``yaw (K,)``: a
        plane fitted to the terrain under the wheels (vectorised over samples and wheels)."""
        k = len(yaw)
        cos_sin = np.empty((2, 1, k))
        np.cos(yaw, out=cos_sin[0, 0])
        np.sin(yaw, out=cos_sin[1, 0])
        # wheel contacts (2, W, K), samples innermost: x + cos bx - sin by, y + sin bx + cos by
        contacts = xy.T[:, None, :] + cos_sin * self._wheel_x
        contacts += cos_sin[::-1] * self._wheel_y_signed
        heights = self.world.terrain.height_at(contacts.reshape(2, -1)).reshape(-1, k)  # (W, K)
        a, b, c = self._fit @ heights  # plane z = a + b bx + c by at every sample
        norm = np.sqrt(1.0 + b * b + c * c)
        rp = np.empty((k, 2))  # written in place: the trace keeps it without a column_stack
        np.arcsin(c / norm, out=rp[:, 0])  # left side up: positive roll
        np.negative(np.arctan(b), out=rp[:, 1])  # nose up when the terrain rises ahead: negative pitch (ZYX)
        z = a + self.robot.base_height * (1.0 / norm)
        return z, rp

    def _set_state(self, x: float, y: float, yaw: float, z: float, roll: float, pitch: float, t: float) -> None:
        self._state = RoverState(np.array([x, y, z]), np.array([roll, pitch, wrap_angle(yaw)]), time=t)

    # ------------------------------------------------------------------ interface shared with physics
    def reset(self, xy: np.ndarray, yaw: float, rng: np.random.Generator | None = None) -> RoverState:
        x, y = float(xy[0]), float(xy[1])
        z, rp = self._poses(np.array([[x, y]]), np.array([yaw]))
        self._set_state(x, y, yaw, float(z[0]), float(rp[0, 0]), float(rp[0, 1]), 0.0)
        return self._state

    def execute(
        self, waypoint: np.ndarray, controller: TurnThenDrive, pose_estimate: PoseEstimate | None = None
    ) -> WaypointResult:
        st = self._state
        x0, y0, yaw0 = float(st.position[0]), float(st.position[1]), st.yaw
        est_xy, est_yaw = pose_estimate(st) if pose_estimate else (st.xy, yaw0)
        dx, dy = float(waypoint[0] - est_xy[0]), float(waypoint[1] - est_xy[1])
        distance = math.hypot(dx, dy)
        if distance <= controller.position_tolerance:
            return self._finish("reached", 0.0, np.array([[x0, y0]]), np.array([yaw0]), np.array([0.0]), 0.0)
        turn = float(wrap_angle(math.atan2(dy, dx) - est_yaw))
        if abs(turn) <= controller.heading_tolerance:
            turn = 0.0  # already facing it: the controller drives straight away (and steers the rest)
        # the rover executes the motion the controller planned from its estimate, starting from its true pose
        n_turn = int(math.ceil(abs(turn) / TURN_SAMPLE_RAD))
        heading = yaw0 + turn
        drive = max(distance - controller.position_tolerance, 0.0)
        n_drive = max(int(math.ceil(drive / self.cfg.sample_spacing)), 1)
        s = drive * np.arange(1, n_drive + 1) / n_drive
        # samples: the start, n_turn turning in place, n_drive along the straight drive (written in place)
        m = 1 + n_turn  # the first drive sample
        xy, yaws, times = np.empty((m + n_drive, 2)), np.empty(m + n_drive), np.empty(m + n_drive)
        xy[:m] = x0, y0
        xy[m:, 0] = x0 + s * math.cos(heading)
        xy[m:, 1] = y0 + s * math.sin(heading)
        yaws[0], times[0] = yaw0, 0.0
        turn_yaw = np.add(yaw0, turn * np.arange(1, m) / max(n_turn, 1), out=yaws[1:m])
        np.divide(np.abs(turn_yaw - yaw0), controller.turn_speed, out=times[1:m])
        yaws[m:] = heading
        np.add(abs(turn) / controller.turn_speed, s / controller.cruise_speed, out=times[m:])
        result = self._check_path(xy, yaws, times, s, m)
        if result.outcome == "halted" and result.path_length == 0.0 and self.robot.guard_retreat > 0:
            return self._back_off(result)
        return result

    def _back_off(self, halted: WaypointResult) -> WaypointResult:
        """After a guard halt that drove no distance: reverse ``guard_retreat`` metres straight behind the
        rover's heading (see the module docstring), after ``guard_pause_s`` standing still, at its retreat speed;
        one result for the turn and the reverse, with the halt's ``hazard_xy``."""
        st = self._state
        x0, y0, yaw = float(st.position[0]), float(st.position[1]), st.yaw
        reach = self.robot.guard_retreat
        n = max(int(math.ceil(reach / self.cfg.sample_spacing)), 1)
        s = reach * np.arange(1, n + 1) / n
        xy = np.empty((n + 1, 2))
        xy[0] = x0, y0
        xy[1:, 0] = x0 - s * math.cos(yaw)
        xy[1:, 1] = y0 - s * math.sin(yaw)
        times = np.concatenate([[0.0], self.robot.guard_pause_s + s / self.robot.retreat_speed])
        back = self._check_path(xy, np.full(n + 1, yaw), times, s, 1, reverse=True)
        outcome = back.outcome if back.outcome in ("tipover", "collision", "out_of_bounds") else "halted"
        t0, t1 = halted.trace_t, back.trace_t
        assert t0 is not None and t1 is not None  # _check_path always times its samples
        return WaypointResult(
            outcome,
            halted.duration + back.duration,
            back.path_length,
            np.concatenate([halted.trace_xy, back.trace_xy[1:]]),
            np.concatenate([halted.trace_tilt_deg, back.trace_tilt_deg[1:]]),
            np.concatenate([halted.trace_rp, back.trace_rp[1:]]),
            halted.detail,
            np.concatenate([t0, halted.duration + t1[1:]]),
            hazard_xy=halted.hazard_xy,
        )

    def _check_path(
        self,
        xy: np.ndarray,
        yaws: np.ndarray,
        times: np.ndarray,
        drive_s: np.ndarray,
        m: int,
        *,
        reverse: bool = False,
    ) -> WaypointResult:
        """Walk the sampled path (``xy (K, 2)``, ``yaws``, ``times``; samples from ``m`` on lie ``drive_s``
        metres along the drive) and stop at the first sample that breaks a limit. ``reverse``: the guard's back
        off (a nose-down slope is the one it cannot climb; a guard halt stops it, backing off no further)."""
        xs, ys = xy[:, 0], xy[:, 1]
        z, rp = self._poses(xy, yaws)
        tilt = tilt_deg(rp[:, 0], rp[:, 1])
        robot = self.robot
        # one row per sample, one column per failure in FAILURE_CHECKS order: the first True in row-major
        # order is the earliest failing sample and, on a tie, the failure listed first
        failed = np.empty((len(xs), len(FAILURE_CHECKS)), dtype=bool)
        np.logical_not(self.world.terrain.contains(xs, ys), out=failed[:, 0])
        np.greater(tilt, robot.tipover_deg, out=failed[:, 2])
        if reverse:  # backing up a slope: the nose points down it
            np.greater(rp[:, 1], self._max_slope_rad, out=failed[:, 3])
        else:
            np.less(rp[:, 1], -self._max_slope_rad, out=failed[:, 3])  # nose-up pitch above the limit
        if self._collision_clearance is None:
            failed[:, 4] = False
        else:
            np.less(self._clearance_at(xs, ys), robot.radius, out=failed[:, 4])
        if robot.tilt_guard_deg is None:
            failed[:, 1] = False
        else:
            np.greater(tilt, robot.tilt_guard_deg, out=failed[:, 1])
            if reverse:  # the guard re-arms once the tilt is back under it (as in the physics mode)
                failed[:, 1] &= np.logical_or.accumulate(~failed[:, 1])
        failed[0] = False  # the starting sample was checked when the rover got there
        flat = int(failed.argmax())
        first, check = divmod(flat, len(FAILURE_CHECKS))
        outcome = FAILURE_CHECKS[check] if failed[first, check] else "reached"
        if outcome == "halted" and not reverse and first >= m and self.cfg.guard_overshoot > 0:
            tipped = self._carried_past_guard(tilt, drive_s, first, m)
            if tipped is not None:
                outcome, first = "tipover", tipped
        end = first if outcome != "reached" else len(xs) - 1
        if outcome in ("stuck", "halted"):
            end = max(first - 1, 0)  # wheels spin at the foot of the slope / the guard stops the rover before it
        keep = np.arange(end + 1)
        trace_t = times[: end + 1].copy()
        length = float(drive_s[end - m]) if end >= m else 0.0  # turning in place covers no distance
        if outcome == "halted" and end >= m and not reverse:  # back along the drive, guard_retreat before the stop
            along = np.concatenate([[0.0], drive_s[: end - m + 1]])  # samples m - 1 (the drive's start) .. end
            # the nearest sample at least guard_retreat back, or the drive's start
            stop = m - 1 + max(int(np.searchsorted(along, along[-1] - robot.guard_retreat, side="right")) - 1, 0)
            back = np.arange(end - 1, stop - 1, -1)
            keep = np.concatenate([keep, back])
            back_s = along[-1] - along[back - (m - 1)]  # metres backed off at each sample
            trace_t = np.concatenate([trace_t, times[end] + robot.guard_pause_s + back_s / robot.retreat_speed])
            length += length - (float(drive_s[stop - m]) if stop >= m else 0.0)
            end = stop
        self._set_state(
            float(xs[end]),
            float(ys[end]),
            float(yaws[end]),
            float(z[end]),
            float(rp[end, 0]),
            float(rp[end, 1]),
            self._state.time + float(trace_t[-1]),
        )
        if outcome == "stuck":  # the wheels spin until the controller's stuck window runs out
            trace_t[-1] += self.cfg.stuck_window_s
            self._state.time += self.cfg.stuck_window_s
        result = self._finish(outcome, float(trace_t[-1]), xy[keep], tilt[keep], rp[keep], length)
        result.trace_t = trace_t
        if outcome in ("stuck", "halted") and first >= m:
            result.hazard_xy = xy[first].copy()
        elif outcome in ("stuck", "halted"):  # while turning in place: that way is barred from here, so mark it ahead
            result.hazard_xy = xy[0] + hazard_ahead(robot.length, float(yaws[-1]))
        return result

    def _carried_past_guard(self, tilt: np.ndarray, drive_s: np.ndarray, first: int, m: int) -> int | None:
        """The drive sample where the rover tips over while carrying on ``cfg.guard_overshoot`` metres past the
        guard's trip at sample ``first`` (that sample included); ``None`` if it stays under the limit."""
        reach = drive_s[first - m] + self.cfg.guard_overshoot
        for j in range(first, len(tilt)):
            if drive_s[j - m] > reach:
                break
            if tilt[j] > self.robot.tipover_deg:
                return j
        return None

    def _finish(
        self,
        outcome: str,
        duration: float,
        trace_xy: np.ndarray,
        trace_tilt: np.ndarray,
        trace_rp: np.ndarray,
        length: float,
    ) -> WaypointResult:
        if trace_rp.ndim == 1:  # "reached" without moving: one sample of the current attitude
            trace_rp = self._state.rpy[None, :2].copy()
            trace_tilt = np.array([self._state.tilt_deg])
        return WaypointResult(outcome, duration, length, trace_xy, trace_tilt, trace_rp)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ rendering support
    def scene(self):
        """The PyBullet scene with the robot at the current pose (built on first use, for rendering)."""
        if self._scene is None:
            from diana_lab.sim.pybullet_scene import PybulletScene

            self._scene = PybulletScene(self.world, self.robot)
        self._scene.set_pose(self._state.position, self._state.rpy)
        return self._scene

    def close(self) -> None:
        if self._scene is not None:
            self._scene.close()
            self._scene = None

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_scene"] = None
        return state
