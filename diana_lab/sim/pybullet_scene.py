"""One PyBullet client holding the static scene of a :class:`World` and one rover loaded from its URDF.

Both dynamics use it: the physics model steps it, the kinematic model only poses the rover in it (rendering).
What this module settles, once:

* The terrain is a ``GEOM_HEIGHTFIELD`` built straight from ``terrain.heights`` (row-major ``[iy, ix]``, so
  ``numHeightfieldRows`` is the number of samples along x). Bullet centres a heightfield on its bounding box,
  so the body goes to ``z = (max + min) / 2``; it triangulates each cell along the same diagonal as
  :class:`~diana_lab.sim.terrain.Terrain` (pinned by ``tests/sim/test_pybullet_scene.py``).
* Obstacles are static bodies: convex ones a convex-hull mesh (cheap, robust contacts), the others a concave
  triangle mesh (``GEOM_FORCE_CONCAVE_TRIMESH``; static bodies only, which obstacles are).
* Poses are those of the URDF's base link frame. PyBullet's ``*BasePositionAndOrientation`` work on the base's
  centre of mass instead; :meth:`PybulletScene.set_pose` and :meth:`PybulletScene.base_pose` convert.
* A rocker-bogie differential cannot be written in URDF: when the URDF has joints named ``left_rocker`` and
  ``right_rocker`` a ``JOINT_GEAR`` constraint ties them. Bullet's gear row enforces
  ``qdot_left + ratio * qdot_right = 0`` (``btMultiBodyGearConstraint``), so ``ratio = +1`` makes the rockers
  turn by equal and opposite angles relative to the body, i.e. the body pitch stays at the mean of the two
  rockers' pitches (the sign is pinned by a test). A small ``erp`` removes the drift of the velocity-level
  constraint. All other non-wheel movable joints are made passive (PyBullet motorises every joint by default).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pybullet as pb
import pybullet_data

from diana_lab.config.sim import RobotConfig
from diana_lab.core.validation import ConfigError
from diana_lab.sim.world import World

ASSETS = Path(__file__).resolve().parents[1] / "assets"
DIFFERENTIAL_JOINTS = ("left_rocker", "right_rocker")
DIFFERENTIAL_MAX_TORQUE = 2000.0  # N m: the gear is a rigid linkage, never the weak part
DIFFERENTIAL_ERP = 0.2

__all__ = ["ASSETS", "PybulletScene", "resolve_urdf"]


def resolve_urdf(spec: str) -> Path:
    """``package:<p>`` -> ``diana_lab/assets/<p>``, ``pybullet_data:<p>`` -> PyBullet's data, else a path."""
    if spec.startswith("package:"):
        path = ASSETS / spec.removeprefix("package:")
    elif spec.startswith("pybullet_data:"):
        path = Path(pybullet_data.getDataPath()) / spec.removeprefix("pybullet_data:")
    else:
        path = Path(spec).expanduser()
    if not path.is_file():
        raise ConfigError(
            f"robot.urdf: '{spec}' resolves to '{path}', which does not exist "
            "(expected 'package:urdf/<name>.urdf', 'pybullet_data:<path>' or a file path)"
        )
    return path


@contextlib.contextmanager
def _quiet_fds() -> Iterator[None]:
    """Silence PyBullet's C-level stdout/stderr chatter (URDF importer warnings) while loading."""
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no usable file descriptors (unusual embedding): just load loudly
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


def _want_gui(gui: bool) -> bool:
    return gui and bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class PybulletScene:
    """The static world and the rover in their own PyBullet client (``DIRECT`` unless ``gui`` + a display)."""

    def __init__(self, world: World, robot: RobotConfig, *, gui: bool = False) -> None:
        self.world, self.robot = world, robot
        self._closed = True
        self.gui = _want_gui(gui)
        self.client = pb.connect(pb.GUI) if self.gui else -1
        if self.client < 0:  # no GUI wanted, or PyBullet refused one (it allows one GUI per process)
            self.gui = False
            self.client = pb.connect(pb.DIRECT)
        if self.client < 0:
            raise RuntimeError("PyBullet: could not connect a physics client")
        self._closed = False
        try:
            pb.setRealTimeSimulation(0, physicsClientId=self.client)
            if self.gui:
                pb.configureDebugVisualizer(pb.COV_ENABLE_GUI, 0, physicsClientId=self.client)
            self.terrain_id = self._add_terrain()
            self.obstacle_ids = tuple(self._add_obstacle(i) for i in range(len(world.obstacles)))
            self.robot_id = self._load_robot()
            self.joints = self._joint_table()
            self.wheels_left = self._wheel_indices("robot.wheel_joints_left", robot.wheel_joints_left)
            self.wheels_right = self._wheel_indices("robot.wheel_joints_right", robot.wheel_joints_right)
            self.differential_id = self._add_differential()
            self._free_passive_joints()
            info = pb.getDynamicsInfo(self.robot_id, -1, physicsClientId=self.client)
            self._com_in_base = (info[3], info[4])  # base link frame -> centre-of-mass frame
            self._base_in_com = pb.invertTransform(*self._com_in_base)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ building
    def _add_terrain(self) -> int:
        t = self.world.terrain
        ny, nx = t.shape
        shape = pb.createCollisionShape(
            pb.GEOM_HEIGHTFIELD,
            meshScale=[t.dx, t.dy, 1.0],
            heightfieldData=t.heights.ravel().tolist(),
            numHeightfieldRows=nx,
            numHeightfieldColumns=ny,
            physicsClientId=self.client,
        )
        body = pb.createMultiBody(
            0,
            shape,
            basePosition=[0.0, 0.0, 0.5 * (t.max_height + t.min_height)],
            physicsClientId=self.client,
        )
        pb.changeVisualShape(body, -1, rgbaColor=[0.76, 0.45, 0.28, 1.0], physicsClientId=self.client)
        return body

    def _add_obstacle(self, index: int) -> int:
        ob = self.world.obstacles[index]
        centre = ob.centre
        local = (ob.vertices - centre).tolist()
        indices = ob.triangles.ravel().tolist()
        if ob.convex:
            shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=local, physicsClientId=self.client)
        else:
            shape = pb.createCollisionShape(
                pb.GEOM_MESH,
                vertices=local,
                indices=indices,
                flags=pb.GEOM_FORCE_CONCAVE_TRIMESH,
                physicsClientId=self.client,
            )
        visual = pb.createVisualShape(
            pb.GEOM_MESH,
            vertices=local,
            indices=indices,
            rgbaColor=[0.45, 0.40, 0.36, 1.0],
            physicsClientId=self.client,
        )
        return pb.createMultiBody(0, shape, visual, basePosition=centre.tolist(), physicsClientId=self.client)

    def _load_robot(self) -> int:
        path = resolve_urdf(self.robot.urdf)
        # inertias from the file (not recomputed from the collision shapes); fixed links merged: fewer bodies
        flags = pb.URDF_USE_INERTIA_FROM_FILE | pb.URDF_MERGE_FIXED_LINKS
        with _quiet_fds():
            body = pb.loadURDF(str(path), [0.0, 0.0, 0.0], flags=flags, physicsClientId=self.client)
        if body < 0:
            raise ConfigError(f"robot.urdf: PyBullet could not load '{path}'")
        return body

    def _joint_table(self) -> dict[str, tuple[int, int]]:
        """Joint name -> (index, type)."""
        table = {}
        for j in range(pb.getNumJoints(self.robot_id, physicsClientId=self.client)):
            info = pb.getJointInfo(self.robot_id, j, physicsClientId=self.client)
            table[info[1].decode()] = (j, info[2])
        return table

    def _wheel_indices(self, key: str, names: Sequence[str]) -> tuple[int, ...]:
        indices = []
        for name in names:
            if name not in self.joints:
                movable = sorted(n for n, (_, kind) in self.joints.items() if kind != pb.JOINT_FIXED)
                raise ConfigError(
                    f"{key}: joint '{name}' is not in '{self.robot.urdf}'; "
                    f"its movable joints are {', '.join(movable) or '(none)'}"
                )
            j, kind = self.joints[name]
            if kind != pb.JOINT_REVOLUTE:
                urdf = self.robot.urdf
                raise ConfigError(f"{key}: joint '{name}' in '{urdf}' is not revolute or continuous")
            indices.append(j)
        return tuple(indices)

    def _add_differential(self) -> int | None:
        if not all(name in self.joints for name in DIFFERENTIAL_JOINTS):
            return None
        left, right = (self.joints[name][0] for name in DIFFERENTIAL_JOINTS)
        cid = pb.createConstraint(
            self.robot_id,
            left,
            self.robot_id,
            right,
            pb.JOINT_GEAR,
            [0, 1, 0],
            [0, 0, 0],
            [0, 0, 0],
            physicsClientId=self.client,
        )
        pb.changeConstraint(
            cid,
            gearRatio=1.0,
            maxForce=DIFFERENTIAL_MAX_TORQUE,
            erp=DIFFERENTIAL_ERP,
            physicsClientId=self.client,
        )
        return cid

    def _free_passive_joints(self) -> None:
        wheels = set(self.wheels_left) | set(self.wheels_right)
        for j, kind in self.joints.values():
            if kind != pb.JOINT_FIXED and j not in wheels:
                pb.setJointMotorControl2(
                    self.robot_id,
                    j,
                    pb.VELOCITY_CONTROL,
                    targetVelocity=0.0,
                    force=0.0,
                    physicsClientId=self.client,
                )

    # ------------------------------------------------------------------ queries and poses
    @property
    def wheel_indices(self) -> tuple[int, ...]:
        return self.wheels_left + self.wheels_right

    @property
    def movable_joints(self) -> tuple[int, ...]:
        return tuple(j for j, kind in self.joints.values() if kind != pb.JOINT_FIXED)

    def set_pose(self, position: Sequence[float], rpy: Sequence[float]) -> None:
        """Put the base link frame at ``position`` with roll/pitch/yaw ``rpy``, at rest, joints at zero."""
        orn = pb.getQuaternionFromEuler([float(a) for a in rpy])
        pos, orn = pb.multiplyTransforms([float(v) for v in position], orn, *self._com_in_base)
        c = self.client
        pb.resetBasePositionAndOrientation(self.robot_id, pos, orn, physicsClientId=c)
        pb.resetBaseVelocity(self.robot_id, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=c)
        for j in self.movable_joints:
            pb.resetJointState(self.robot_id, j, 0.0, 0.0, physicsClientId=c)

    def base_pose(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Position and quaternion (x, y, z, w) of the base link frame."""
        pos, orn = pb.getBasePositionAndOrientation(self.robot_id, physicsClientId=self.client)
        return pb.multiplyTransforms(pos, orn, *self._base_in_com)

    def base_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(position, rpy, linear, angular velocity)`` of the base (velocities of its centre of mass)."""
        pos, orn = self.base_pose()
        lin, ang = pb.getBaseVelocity(self.robot_id, physicsClientId=self.client)
        return np.array(pos), np.array(pb.getEulerFromQuaternion(orn)), np.array(lin), np.array(ang)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            with contextlib.suppress(pb.error):
                pb.disconnect(physicsClientId=self.client)

    def __enter__(self) -> PybulletScene:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # a forgotten scene must not leak a physics server
        with contextlib.suppress(Exception):
            self.close()
