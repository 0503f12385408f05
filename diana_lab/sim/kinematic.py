"""Kinematic dynamics: the rover follows the controller's ideal path exactly; the terrain sets its pose.

This is the fast mode for training. The turn-then-drive path is computed analytically, then sampled every
``cfg.sample_spacing`` metres (and every 15 degrees of turning); at every sample the rover's height, roll and
pitch come from a least-squares plane through the terrain under its wheels (one vectorised solve for all
samples). The first sample that violates a limit ends the waypoint:

* ``tipover``: tilt above ``robot.tipover_deg``;
* ``stuck``: nose-up pitch above ``robot.max_slope_deg`` (the wheels cannot climb it);
* ``collision``: an obstacle taller than ``robot.ground_clearance`` within ``robot.radius`` of the centre;
* ``out_of_bounds``: the centre leaves the terrain.

PyBullet is used only for rendering, through the same scene as the physics mode, built lazily.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cached_property

import numpy as np

from diana_lab.config.sim import KinematicConfig, RobotConfig
from diana_lab.sim.controller import TurnThenDrive, wrap_angle
from diana_lab.sim.state import RoverState, WaypointResult, tilt_deg
from diana_lab.sim.world import World

PoseEstimate = Callable[[RoverState], tuple[np.ndarray, float]]
TURN_SAMPLE_RAD = math.radians(15.0)


class KinematicDynamics:
    """Exact path following with terrain-conforming pose; see the module docstring for the rules."""

    def __init__(self, cfg: KinematicConfig, world: World, robot: RobotConfig) -> None:
        self.cfg, self.world, self.robot = cfg, world, robot
        half = robot.track_width / 2.0
        self._wheels = np.array([(ax, side) for ax in robot.axle_x for side in (half, -half)])  # body frame
        design = np.column_stack([np.ones(len(self._wheels)), self._wheels])
        self._fit = np.linalg.pinv(design)  # (3, W): plane coefficients (a, b, c) of z = a + b*bx + c*by
        self._tan_tip = math.tan(math.radians(robot.tipover_deg))
        self._state = RoverState()
        self._scene = None

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> RoverState:
        return self._state

    @cached_property
    def _collision_clearance(self) -> tuple[np.ndarray, float, float, float]:
        """Distance to the nearest obstacle cell the chassis cannot pass over (inf without obstacles)."""
        from scipy.ndimage import distance_transform_edt

        om = self.world.obstacle_map
        blocking = om.height > self.robot.ground_clearance
        if not blocking.any():  # a 1 x 1 sentinel: _clearance_at skips the lookup
            return np.full((1, 1), np.inf), om.resolution, om.x_min, om.y_min
        clearance = distance_transform_edt(~blocking) * om.resolution
        return clearance, om.resolution, om.x_min, om.y_min

    def _clearance_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        clearance, res, x0, y0 = self._collision_clearance
        if clearance.size == 1:  # nothing the chassis could hit in this world
            return np.full(np.shape(x), np.inf)
        ny, nx = clearance.shape
        ix = np.clip(np.rint((x - x0) / res).astype(np.int64), 0, nx - 1)
        iy = np.clip(np.rint((y - y0) / res).astype(np.int64), 0, ny - 1)
        return clearance[iy, ix]

    def _poses(self, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Height of the base, roll and pitch at each sample (vectorised plane fit under the wheels)."""
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        bx, by = self._wheels[:, 0], self._wheels[:, 1]
        wx = x[:, None] + c * bx - s * by
        wy = y[:, None] + s * bx + c * by
        coeff = self.world.height(wx, wy) @ self._fit.T  # (K, 3)
        a, b, cc = coeff[:, 0], coeff[:, 1], coeff[:, 2]
        norm = np.sqrt(1.0 + b * b + cc * cc)
        pitch = -np.arctan(b)  # nose up when the terrain rises ahead: negative pitch (ZYX)
        roll = np.arcsin(cc / norm)  # left side up: positive roll
        z = a + self.robot.base_height * (1.0 / norm)
        return z, roll, pitch

    def _set_state(self, x: float, y: float, yaw: float, z: float, roll: float, pitch: float, t: float) -> None:
        self._state = RoverState(np.array([x, y, z]), np.array([roll, pitch, wrap_angle(yaw)]), time=t)

    # ------------------------------------------------------------------ interface shared with physics
    def reset(self, xy: np.ndarray, yaw: float, rng: np.random.Generator | None = None) -> RoverState:
        x, y = float(xy[0]), float(xy[1])
        z, roll, pitch = self._poses(np.array([x]), np.array([y]), np.array([yaw]))
        self._set_state(x, y, yaw, float(z[0]), float(roll[0]), float(pitch[0]), 0.0)
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
        turn_yaw = yaw0 + turn * np.arange(1, n_turn + 1) / max(n_turn, 1)
        heading = yaw0 + turn
        drive = max(distance - controller.position_tolerance, 0.0)
        n_drive = max(int(math.ceil(drive / self.cfg.sample_spacing)), 1)
        s = drive * np.arange(1, n_drive + 1) / n_drive
        xs = np.concatenate([[x0], np.full(n_turn, x0), x0 + s * math.cos(heading)])
        ys = np.concatenate([[y0], np.full(n_turn, y0), y0 + s * math.sin(heading)])
        yaws = np.concatenate([[yaw0], turn_yaw, np.full(n_drive, heading)])
        times = np.concatenate(
            [
                [0.0],
                np.abs(turn_yaw - yaw0) / controller.turn_speed,
                abs(turn) / controller.turn_speed + s / controller.cruise_speed,
            ]
        )
        travelled = np.concatenate([np.zeros(1 + n_turn), s])
        return self._check_path(xs, ys, yaws, times, travelled)

    def _check_path(
        self, xs: np.ndarray, ys: np.ndarray, yaws: np.ndarray, times: np.ndarray, travelled: np.ndarray
    ) -> WaypointResult:
        z, roll, pitch = self._poses(xs, ys, yaws)
        tilt = tilt_deg(roll, pitch)
        robot = self.robot
        failures = {
            "out_of_bounds": ~self.world.terrain.contains(xs, ys),
            "tipover": tilt > robot.tipover_deg,
            "stuck": -pitch > math.radians(robot.max_slope_deg),
            "collision": self._clearance_at(xs, ys) < robot.radius,
        }
        first, outcome = len(xs), "reached"
        for name, mask in failures.items():
            hits = np.flatnonzero(mask[1:])  # the starting sample was checked when the rover got there
            if hits.size and hits[0] + 1 < first:
                first, outcome = int(hits[0]) + 1, name
        end = first if outcome != "reached" else len(xs) - 1
        if outcome == "stuck":
            end = max(first - 1, 0)  # wheels spin at the foot of the slope: the rover stays where it was
        keep = slice(0, end + 1)
        self._set_state(
            float(xs[end]),
            float(ys[end]),
            float(yaws[end]),
            float(z[end]),
            float(roll[end]),
            float(pitch[end]),
            self._state.time + float(times[end]),
        )
        trace_t = times[keep].copy()
        if outcome == "stuck":  # the wheels spin until the controller's stuck window runs out
            trace_t[-1] += self.cfg.stuck_window_s
            self._state.time += self.cfg.stuck_window_s
        rp = np.column_stack([roll[keep], pitch[keep]])
        result = self._finish(
            outcome,
            float(trace_t[-1]),
            np.column_stack([xs[keep], ys[keep]]),
            tilt[keep],
            rp,
            float(travelled[end]),
        )
        result.trace_t = trace_t
        return result

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
