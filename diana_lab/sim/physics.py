"""Physics dynamics: the rover's URDF driven by the turn-then-drive controller in PyBullet.

Same interface as :class:`diana_lab.sim.kinematic.KinematicDynamics` (``reset``, ``execute``, ``state``,
``close``). The controller runs at ``cfg.controller.rate_hz`` on the (estimated) pose and sets skid-steer
wheel velocity motors; PyBullet steps at ``cfg.time_step`` in between. All checks run at the control rate,
except contacts with obstacles, which are checked every physics step while an obstacle is close. Outcomes:

* ``reached``: the controller is within its position tolerance (judged on the pose it is given);
* ``gave_up``: ``controller.time_limit(distance, heading_error)`` ran out;
* ``collision``: any contact between the rover and an obstacle body;
* ``tipover``: tilt above ``robot.tipover_deg``;
* ``stuck``: less than ``cfg.stuck_distance`` of progress (translation plus the wheel arc of any rotation)
  within ``cfg.stuck_window_s`` while the controller commands motion;
* ``out_of_bounds``: the rover's centre leaves the terrain;
* ``halted`` (with ``robot.tilt_guard_deg``, the rover's tilt fault protection): the tilt passed the guard
  (below the tip-over limit); the rover stopped there, stood ``robot.guard_pause_s`` seconds with its wheels
  held, and backed ``robot.guard_retreat`` metres at ``robot.guard_retreat_speed`` (never past where the drive
  began; tripped while turning in place, that far straight back, as in the kinematic mode) before the waypoint
  ended (the back-off gets its own time on top of the controller's limit); the guard re-arms once the tilt is
  back under it, and stops the back-off where it passes again. ``hazard_xy`` is where the guard tripped (while
  turning in place: half a rover length towards the waypoint); a ``stuck`` while driving forward reports half a
  rover length ahead;
* ``sim_error``: a non-finite or absurd state (speed above 20 m/s, spin above 50 rad/s, fallen through the
  terrain) or a PyBullet error. ``state`` then stays at the last sane pose (finite observations and reward for
  the episode's last step), and the next ``reset`` rebuilds the PyBullet client, since a NaN body can leave
  it broken for good (the rover then falls through the terrain at every spawn).

Contact model, and why. PyBullet's multibody solver resolves friction along two directions fixed in the world
(not along the slip velocity), so an isotropic wheel friction makes a skid-steer rover's ability to turn in
place depend on its world heading (it nearly stalls when aligned with the world axes). Pyramid friction
(``enableConeFriction=0``) plus a lower friction along the wheel axle (anisotropic friction
``WHEEL_LATERAL_FRICTION``) removes the stall and gives turn rates near what the Coulomb model of a skid
steer predicts (about 2/3 of the commanded rate for the Jackal on flat ground). ``cfg.friction`` is the
terrain's (and obstacles') coefficient; Bullet multiplies the two bodies' coefficients, and wheels use 1.0.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pybullet as pb

from diana_lab.config.sim import PhysicsConfig, RobotConfig
from diana_lab.sim.controller import TurnThenDrive, wrap_angle
from diana_lab.sim.pybullet_scene import PybulletScene
from diana_lab.sim.state import Outcome, RoverState, WaypointResult, hazard_ahead, tilt_deg
from diana_lab.sim.world import World

PoseEstimate = Callable[[RoverState], tuple[np.ndarray, float]]

GRAVITY = 9.81
WHEEL_LATERAL_FRICTION = 0.5  # friction along the wheel axle relative to the rolling direction (see above)
# Reflected inertia of the geared drive motors at the wheel axle, as a fraction of (mass per wheel) x r^2.
# Real: rotor inertia x gear ratio^2 (e.g. 2e-5 kg m^2 x 78^2 = 0.12 kg m^2 for a Husky wheel). Needed too:
# PyBullet's velocity motors are not warm-started while contact friction is, so with a bare wheel's inertia
# they do not converge within ~10 solver iterations when a loaded wheel must break static friction, and the
# rover stalls on uneven ground (on a diagonal wheel pair) with its motors far below their torque limit.
DRIVE_INERTIA = 0.3
CHASSIS_FRICTION = 0.8  # a high-centred chassis scrapes: a bit less grip than a tyre
SPAWN_CLEARANCE = 0.02  # m from the wheels' lowest point to the highest terrain under the footprint at spawn
CONTACT_BREAKING_THRESHOLD = 0.005  # m; Bullet's 0.02 keeps stale points of rolling wheels (slower, stickier)
MAX_SPEED = 20.0  # m/s: anything faster is a blown-up simulation
MAX_SPIN = 50.0  # rad/s of the base
FALL_THROUGH_DEPTH = 0.5  # m below the lowest terrain point: the rover tunnelled through the heightfield

__all__ = ["PhysicsDynamics"]


class PhysicsDynamics:
    """A PyBullet rover on a world; see the module docstring for the contact model and the outcomes."""

    def __init__(self, cfg: PhysicsConfig, world: World, robot: RobotConfig, *, gui: bool = False) -> None:
        self.cfg, self.world, self.robot = cfg, world, robot
        self._gui = gui
        self._steps_per_tick = max(1, round(1.0 / (cfg.controller.rate_hz * cfg.time_step)))
        self._tick = self._steps_per_tick * cfg.time_step
        self._build_scene()
        if world.obstacles:  # bounding circles (xy) for the cheap "is an obstacle close?" test
            self._ob_xy = np.array([ob.centre[:2] for ob in world.obstacles])
            self._ob_r = np.array(
                [np.max(np.linalg.norm(ob.vertices[:, :2] - ob.centre[:2], axis=1)) for ob in world.obstacles]
            )
        self._time = 0.0
        self._bounds = world.bounds
        # below the lowest terrain point by this much: fell through the heightfield (tunnelling)
        self._floor = world.terrain.min_height - FALL_THROUGH_DEPTH
        # after a sim_error: the last sane state (what ``state`` reports until the next reset rebuilds the scene)
        self._wreck: RoverState | None = None

    # ------------------------------------------------------------------ set-up
    def _build_scene(self) -> None:
        """A fresh PyBullet client with the world, the rover and the contact model of the module docstring."""
        cfg, robot = self.cfg, self.robot
        self._scene = PybulletScene(self.world, robot, gui=self._gui)
        self._client = c = self._scene.client
        self._body = self._scene.robot_id
        pb.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=c)
        pb.setPhysicsEngineParameter(
            fixedTimeStep=cfg.time_step,
            numSubSteps=0,
            numSolverIterations=int(cfg.solver_iterations),
            enableConeFriction=0,
            deterministicOverlappingPairs=1,
            contactBreakingThreshold=CONTACT_BREAKING_THRESHOLD,
            physicsClientId=c,
        )
        self._set_friction()
        self._add_drive_inertia()
        self._wheels = list(self._scene.wheel_indices)
        self._n_left = len(self._scene.wheels_left)
        self._torques = [float(robot.max_wheel_torque)] * len(self._wheels)
        self._obstacles = {bid: i for i, bid in enumerate(self._scene.obstacle_ids)}

    def _set_friction(self) -> None:
        c, body = self._client, self._body
        for bid in (self._scene.terrain_id, *self._scene.obstacle_ids):
            pb.changeDynamics(
                bid,
                -1,
                lateralFriction=float(self.cfg.friction),
                rollingFriction=0.0,
                spinningFriction=0.0,
                restitution=0.0,
                physicsClientId=c,
            )
        wheels = set(self._scene.wheel_indices)
        for link in range(-1, pb.getNumJoints(body, physicsClientId=c)):
            if link in wheels:
                axis = np.abs(self._axle(link))
                aniso = (1.0 - (1.0 - WHEEL_LATERAL_FRICTION) * axis).tolist()  # lower along the axle only
                pb.changeDynamics(
                    body,
                    link,
                    lateralFriction=1.0,
                    anisotropicFriction=aniso,
                    rollingFriction=0.0,
                    spinningFriction=0.0,
                    restitution=0.0,
                    physicsClientId=c,
                )
            else:
                pb.changeDynamics(body, link, lateralFriction=CHASSIS_FRICTION, restitution=0.0, physicsClientId=c)

    def _axle(self, link: int) -> np.ndarray:
        """Unit wheel axle in the link's inertial frame (Bullet's frame for its inertia and friction axes)."""
        c, body = self._client, self._body
        axis = np.asarray(pb.getJointInfo(body, link, physicsClientId=c)[13], dtype=float)  # link frame
        frame = pb.getDynamicsInfo(body, link, physicsClientId=c)[4]
        axis = np.asarray(pb.getMatrixFromQuaternion(frame)).reshape(3, 3).T @ axis
        return axis / max(float(np.linalg.norm(axis)), 1e-9)

    def _add_drive_inertia(self) -> None:
        """Scale each wheel's inertia so that its axle inertia is at least ``DRIVE_INERTIA`` (see above)."""
        c, body, r = self._client, self._body, self.robot
        target = DRIVE_INERTIA * r.mass / len(self._scene.wheel_indices) * r.wheel_radius**2
        for link in self._scene.wheel_indices:
            inertia = np.asarray(pb.getDynamicsInfo(body, link, physicsClientId=c)[2], dtype=float)
            about_axle = float(inertia @ self._axle(link) ** 2)
            if 0.0 < about_axle < target:  # uniform scaling keeps the tensor physically valid
                pb.changeDynamics(
                    body,
                    link,
                    localInertiaDiagonal=(inertia * target / about_axle).tolist(),
                    physicsClientId=c,
                )

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> RoverState:
        """Ground truth of the base link (velocities are those of the base's centre of mass, world frame).

        After a ``sim_error`` it is the last sane state, at rest, until the next reset: the env computes the
        final observation and reward from it, and NaN there would reach the learner's buffers and statistics.
        """
        if self._wreck is not None:
            return self._wreck.copy()
        pos, rpy, lin, ang = self._scene.base_state()
        return RoverState(pos, rpy, lin, ang, self._time)

    def _drive(self, v: float, w: float) -> None:
        """Skid steer: each side's wheels roll at ``(v -+ w * track / 2) / r``, torque-limited."""
        half = 0.5 * self.robot.track_width * w
        r = self.robot.wheel_radius
        left, right = (v - half) / r, (v + half) / r
        targets = [left] * self._n_left + [right] * (len(self._wheels) - self._n_left)
        pb.setJointMotorControlArray(
            self._body,
            self._wheels,
            pb.VELOCITY_CONTROL,
            targetVelocities=targets,
            forces=self._torques,
            physicsClientId=self._client,
        )

    def _footprint_heights(self, x: float, y: float, yaw: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body-frame sample points of the footprint and the terrain heights under them."""
        r = self.robot
        bx, by = np.meshgrid(np.linspace(-r.length / 2, r.length / 2, 7), np.linspace(-r.width / 2, r.width / 2, 5))
        bx, by = bx.ravel(), by.ravel()
        c, s = math.cos(yaw), math.sin(yaw)
        return bx, by, self.world.height(x + c * bx - s * by, y + s * bx + c * by)

    # ------------------------------------------------------------------ interface shared with kinematic
    def reset(self, xy: np.ndarray, yaw: float, rng: np.random.Generator | None = None) -> RoverState:
        """Drop the rover at ``xy`` facing ``yaw`` and let it settle; the clock restarts at 0.

        The rover starts tilted like the plane fitted through the terrain under its footprint and just above
        the highest terrain point under it (``SPAWN_CLEARANCE``), so it falls a couple of centimetres at most
        (no tunnelling, no bounce) while the wheels hold still. ``rng`` is unused: the spawn is deterministic.
        """
        del rng
        if self._wreck is not None:  # a blown-up body can poison the client for good (e.g. NaN in the
            self._scene.close()  # broadphase: the rover then falls through the terrain at every spawn)
            self._build_scene()
            self._wreck = None
        x, y = float(xy[0]), float(xy[1])
        bx, by, hz = self._footprint_heights(x, y, yaw)
        design = np.column_stack([np.ones_like(bx), bx, by])
        (a, b, cc), *_ = np.linalg.lstsq(design, hz, rcond=None)
        norm = math.sqrt(1.0 + b * b + cc * cc)
        pitch, roll = -math.atan(b), math.asin(cc / norm)
        # lift so that the tilted footprint plane clears every sample, then stand on the wheels
        lift = float(np.max(hz - (a + b * bx + cc * by)))
        z = a + lift + self.robot.base_height / norm + SPAWN_CLEARANCE
        self._scene.set_pose([x, y, z], [roll, pitch, yaw])
        self._drive(0.0, 0.0)
        for _ in range(round(self.cfg.settle_time_s / self.cfg.time_step)):
            pb.stepSimulation(physicsClientId=self._client)
        self._time = 0.0
        return self.state

    def execute(
        self, waypoint: np.ndarray, controller: TurnThenDrive, pose_estimate: PoseEstimate | None = None
    ) -> WaypointResult:
        """Drive to ``waypoint`` with the closed-loop controller until it is reached or something fails.

        The loop body runs once per control period; it stays in plain Python floats (no small numpy arrays),
        which matters next to PyBullet's ~40 us per physics step.
        """
        cfg = self.cfg
        st = self.state
        est_xy, est_yaw = pose_estimate(st) if pose_estimate else (st.xy, st.yaw)
        dx, dy = float(waypoint[0] - est_xy[0]), float(waypoint[1] - est_xy[1])
        limit = controller.time_limit(math.hypot(dx, dy), float(wrap_angle(math.atan2(dy, dx) - est_yaw)))
        controller.start()
        x, y = float(st.position[0]), float(st.position[1])
        roll, pitch = float(st.rpy[0]), float(st.rpy[1])
        sane = (tuple(st.position), tuple(st.rpy))  # the last pose that passed the checks
        xs, ys, rolls, pitches = [x], [y], [roll], [pitch]
        anchor_x, anchor_y, anchor_yaw, anchor_t = x, y, st.yaw, 0.0  # last pose that counted as progress
        arm = 0.5 * self.robot.track_width  # rotation progress: the arc the wheels travel
        elapsed, length, outcome, detail = 0.0, 0.0, None, ""
        guard, yaw = self.robot.tilt_guard_deg, st.yaw
        drive_from: tuple[float, float] | None = None  # where the straight drive began
        retreat: tuple[float, float, float] | None = None  # the guard's stop (x, y) and how far to back off
        rearmed = False  # backing off, the tilt has been under the guard again
        tripped_at = 0.0  # when the guard tripped (elapsed s)
        pause, back_speed = self.robot.guard_pause_s, self.robot.retreat_speed
        hazard: np.ndarray | None = None
        phase, trip = "turn", ""
        while True:
            if retreat is None:
                cmd = controller.command(est_xy, est_yaw, waypoint)
                phase, linear, angular = cmd.phase, cmd.linear, cmd.angular
                if phase == "done":
                    outcome = "reached"
                    break
                if phase == "drive" and drive_from is None:
                    drive_from = (x, y)
            elif math.hypot(x - retreat[0], y - retreat[1]) >= retreat[2]:
                outcome, detail = "halted", trip
                break
            elif elapsed - tripped_at < pause:  # the wheels hold while the body settles
                linear, angular = 0.0, 0.0
            else:
                linear, angular = -back_speed, 0.0
            if elapsed >= limit:
                outcome = "halted" if retreat else "gave_up"
                detail = f"time limit {limit:.1f} s" + (f" while backing off ({trip})" if retreat else "")
                break
            self._drive(linear, angular)
            try:
                hit = self._step_tick(x, y)
                pos, orn = self._scene.base_pose()
                lin, ang = pb.getBaseVelocity(self._body, physicsClientId=self._client)
                rpy = pb.getEulerFromQuaternion(orn)
            except pb.error as exc:
                outcome, detail = "sim_error", f"PyBullet: {exc}"
                self._wrecked(*sane)
                break
            elapsed += self._tick
            self._time += self._tick
            outcome, detail, tilt = self._check(pos, rpy, lin, ang, hit)
            if outcome == "sim_error":
                self._wrecked(*sane)  # keep the traces and the state finite
                break
            sane = (pos, rpy)
            length += math.hypot(pos[0] - x, pos[1] - y)
            x, y, yaw = pos[0], pos[1], rpy[2]
            xs.append(x)
            ys.append(y)
            rolls.append(rpy[0])
            pitches.append(rpy[1])
            if outcome is not None:
                break
            # once re-armed, the guard watches its own back-off (after the pause: a settling body hovers at the limit)
            if retreat is not None and guard is not None and elapsed - tripped_at >= pause:
                if tilt <= guard:
                    rearmed = True
                elif rearmed:
                    outcome, detail = "halted", f"{trip}; backing off stopped at {tilt:.1f} deg"
                    break
            if guard is not None and retreat is None and tilt > guard:
                trip = f"tilt guard: {tilt:.1f} deg at ({x:.2f}, {y:.2f})"
                if phase != "drive" or drive_from is None:  # turning in place: back straight off the spot
                    heading = math.atan2(waypoint[1] - est_xy[1], waypoint[0] - est_xy[0])
                    hazard = np.array([x, y]) + hazard_ahead(self.robot.length, heading)
                    retreat = (x, y, self.robot.guard_retreat)
                else:
                    hazard = np.array([x, y])
                    retreat = (x, y, min(self.robot.guard_retreat, math.hypot(x - drive_from[0], y - drive_from[1])))
                # backing off is progress; the stuck window opens once the pause is over
                anchor_x, anchor_y, anchor_yaw, anchor_t = x, y, yaw, elapsed + pause
                tripped_at = elapsed
                limit = max(limit, elapsed + pause + 2.0 * retreat[2] / back_speed + self._tick)
                continue
            progress = math.hypot(x - anchor_x, y - anchor_y) + abs(wrap_angle(yaw - anchor_yaw)) * arm
            if progress >= cfg.stuck_distance:
                anchor_x, anchor_y, anchor_yaw, anchor_t = x, y, yaw, elapsed
            elif elapsed - anchor_t >= cfg.stuck_window_s:
                outcome, detail = "stuck", f"moved {progress:.2f} m in {elapsed - anchor_t:.1f} s"
                if retreat is None and phase == "drive":  # the ground ahead held it
                    hazard = np.array([x, y]) + hazard_ahead(self.robot.length, yaw)
                break
            if pose_estimate:
                est_xy, est_yaw = pose_estimate(
                    RoverState(np.array(pos), np.array(rpy), np.array(lin), np.array(ang), self._time)
                )
            else:
                est_xy, est_yaw = (x, y), yaw
        if self._wreck is None:  # a wrecked client is rebuilt at reset; it may not take commands any more
            self._drive(0.0, 0.0)  # hold the wheels until the next command
        rp = np.column_stack([rolls, pitches])
        return WaypointResult(
            outcome,
            elapsed,
            length,
            np.column_stack([xs, ys]),
            np.asarray(tilt_deg(rp[:, 0], rp[:, 1]), dtype=float),
            rp,
            detail,
            hazard_xy=hazard,
        )

    def _wrecked(self, position: tuple[float, ...], rpy: tuple[float, ...]) -> None:
        """Freeze ``state`` at the last sane pose; the next :meth:`reset` rebuilds the scene."""
        self._wreck = RoverState(np.array(position), np.array(rpy), np.zeros(3), np.zeros(3), self._time)

    def _step_tick(self, x: float, y: float) -> str:
        """Advance one control period; returns the name of an obstacle touched ('' if none).

        Contacts are looked up every physics step, but only while an obstacle's bounding circle is within
        reach of the rover this tick (a glancing touch can be shorter than a control period); else never.
        """
        c = self._client
        near: list[int] = []
        if self._obstacles:
            reach = self.robot.radius + 1.0  # generous: the rover moves < 1 m per control period
            d = np.hypot(self._ob_xy[:, 0] - x, self._ob_xy[:, 1] - y) - self._ob_r
            near = [self._scene.obstacle_ids[i] for i in np.flatnonzero(d < reach)]
        for _ in range(self._steps_per_tick):
            pb.stepSimulation(physicsClientId=c)
            for bid in near:
                if pb.getContactPoints(self._body, bid, physicsClientId=c):
                    return self.world.obstacles[self._obstacles[bid]].name
        return ""

    def _check(
        self,
        pos: tuple[float, ...],
        rpy: tuple[float, ...],
        lin: tuple[float, ...],
        ang: tuple[float, ...],
        hit: str,
    ) -> tuple[Outcome | None, str, float]:
        """The failure (if any) of the state after a control period, most fundamental first, and the tilt
        (degrees; NaN for a non-finite state), which the tilt guard reads too."""
        values = (*pos, *rpy, *lin, *ang)
        if not all(math.isfinite(v) for v in values):
            return "sim_error", "non-finite rover state", math.nan
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, math.cos(rpy[0]) * math.cos(rpy[1])))))
        speed, spin = math.hypot(*lin), math.hypot(*ang)
        if speed > MAX_SPEED or spin > MAX_SPIN:
            return "sim_error", f"exploding state: speed {speed:.3g} m/s, spin {spin:.3g} rad/s", tilt
        if pos[2] < self._floor:
            return "sim_error", f"fell through the terrain (z = {pos[2]:.2f} m)", tilt
        if hit:
            return "collision", f"hit {hit}", tilt
        if tilt > self.robot.tipover_deg:
            return "tipover", f"tilt {tilt:.1f} deg", tilt
        x0, x1, y0, y1 = self._bounds
        if not (x0 <= pos[0] <= x1 and y0 <= pos[1] <= y1):
            return "out_of_bounds", f"left the terrain at ({pos[0]:.1f}, {pos[1]:.1f})", tilt
        return None, "", tilt

    # ------------------------------------------------------------------ life cycle
    def scene(self) -> PybulletScene:
        """The PyBullet scene being simulated (the renderer draws it; same call as the kinematic model's)."""
        return self._scene

    def close(self) -> None:
        self._scene.close()

    def __enter__(self) -> PhysicsDynamics:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
