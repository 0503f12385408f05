"""The PyBullet scene: heightfield placement and order, obstacles, URDF loading, poses, the differential."""

import math

import numpy as np
import pybullet as pb
import pytest
from scipy.spatial import ConvexHull

from diana_lab.config import ConfigError, to_object
from diana_lab.sim.pybullet_scene import PybulletScene, resolve_urdf
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import Obstacle, World

ROBOTS = ["jackal", "husky", "rocker_bogie"]


def ray_heights(scene: PybulletScene, x: np.ndarray, y: np.ndarray, top: float = 50.0) -> tuple[list, np.ndarray]:
    """Body ids hit and hit heights of vertical rays cast down at ``(x, y)``."""
    starts = [[a, b, top] for a, b in zip(x, y)]
    ends = [[a, b, -top] for a, b in zip(x, y)]
    hits = pb.rayTestBatch(starts, ends, physicsClientId=scene.client)
    return [h[0] for h in hits], np.array([h[3][2] for h in hits])


def far_away_robot(scene: PybulletScene) -> None:
    scene.set_pose([1e3, 1e3, 1e3], [0.0, 0.0, 0.0])  # keep the rover out of the rays


@pytest.fixture(scope="module")
def jackal_cfg():
    return to_object("robot", "jackal")


def test_heightfield_matches_terrain_heights_off_grid(jackal_cfg):
    # rough random heights on a non-square grid with different dx and dy: a wrong row/column order, a wrong
    # diagonal or a wrong vertical offset would all be off by decimetres
    rng = np.random.default_rng(3)
    terrain = Terrain(rng.uniform(-1.0, 2.0, size=(23, 37)), 9.0, 5.5)
    with PybulletScene(World("rough", terrain), jackal_cfg) as scene:
        far_away_robot(scene)
        x = rng.uniform(-4.45, 4.45, 400)
        y = rng.uniform(-2.7, 2.7, 400)
        bodies, z = ray_heights(scene, x, y)
        assert set(bodies) == {scene.terrain_id}
        np.testing.assert_allclose(z, terrain.height(x, y), atol=0.01)


def test_heightfield_of_the_mars_yard(mars_yard, jackal_cfg):
    rng = np.random.default_rng(4)
    with PybulletScene(mars_yard, jackal_cfg) as scene:
        far_away_robot(scene)
        x, y = rng.uniform(-24.9, 24.9, 300), rng.uniform(-24.9, 24.9, 300)
        _, z = ray_heights(scene, x, y)
        np.testing.assert_allclose(z, mars_yard.height(x, y), atol=0.01)


def box_obstacle(centre, size, name="box") -> Obstacle:
    corners = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)])
    vertices = corners * np.asarray(size) + np.asarray(centre)
    hull = ConvexHull(vertices)
    return Obstacle(vertices, hull.simplices, name=name, convex=True)


def u_shape(centre) -> Obstacle:
    """A non-convex obstacle: a U of three boxes, open towards +y, 1 m tall, its notch 1 m deep."""
    parts = [
        box_obstacle((-0.5, 0.0, 0.5), (0.5, 1.5, 1.0)),
        box_obstacle((0.5, 0.0, 0.5), (0.5, 1.5, 1.0)),
        box_obstacle((0.0, -0.5, 0.5), (0.5, 0.5, 1.0)),
    ]
    vertices = np.concatenate([p.vertices for p in parts]) + np.asarray(centre)
    triangles = np.concatenate([p.triangles + 8 * i for i, p in enumerate(parts)])
    return Obstacle(vertices, triangles, name="u", convex=False)


def test_obstacles_are_static_bodies_of_the_right_shape(jackal_cfg):
    flat = Terrain(np.zeros((21, 21)), 10.0, 10.0)
    world = World("obstacles", flat, [box_obstacle((2.0, 1.0, 0.25), (0.5, 0.5, 0.5)), u_shape((-2.0, 0.0, 0.0))])
    with PybulletScene(world, jackal_cfg) as scene:
        far_away_robot(scene)
        assert len(scene.obstacle_ids) == 2
        box_id, u_id = scene.obstacle_ids
        assert pb.getDynamicsInfo(box_id, -1, physicsClientId=scene.client)[0] == 0.0  # static
        bodies, z = ray_heights(scene, np.array([2.0, 2.0]), np.array([1.0, 3.0]))
        assert bodies == [box_id, scene.terrain_id]
        assert z == pytest.approx([0.5, 0.0], abs=3e-3)  # convex hulls carry a 1 mm collision margin
        # the U's notch is empty: a convex hull would fill it, the concave mesh does not
        bodies, z = ray_heights(scene, np.array([-2.0, -2.0, -2.5]), np.array([0.5, -0.5, 0.5]))
        assert bodies == [scene.terrain_id, u_id, u_id]
        assert z == pytest.approx([0.0, 1.0, 1.0], abs=1e-3)


@pytest.mark.parametrize("name", ROBOTS)
def test_robot_urdfs_load_with_their_wheel_joints(flat_world, name):
    robot = to_object("robot", name)
    with PybulletScene(flat_world, robot) as scene:
        assert len(scene.wheels_left) == len(robot.wheel_joints_left)
        assert len(scene.wheels_right) == len(robot.wheel_joints_right)
        for names, indices in (
            (robot.wheel_joints_left, scene.wheels_left),
            (robot.wheel_joints_right, scene.wheels_right),
        ):
            for joint_name, j in zip(names, indices):
                info = pb.getJointInfo(scene.robot_id, j, physicsClientId=scene.client)
                assert info[1].decode() == joint_name
                assert info[2] == pb.JOINT_REVOLUTE
        total = sum(
            pb.getDynamicsInfo(scene.robot_id, link, physicsClientId=scene.client)[0]
            for link in range(-1, pb.getNumJoints(scene.robot_id, physicsClientId=scene.client))
        )
        assert total == pytest.approx(robot.mass, rel=0.02)
        assert (scene.differential_id is not None) == (name == "rocker_bogie")


@pytest.mark.parametrize("name", ROBOTS)
def test_set_pose_places_the_base_link_frame(flat_world, name):
    robot = to_object("robot", name)
    with PybulletScene(flat_world, robot) as scene:
        scene.set_pose([1.0, -2.0, 0.7], [0.1, -0.2, 2.5])
        pos, rpy, lin, ang = scene.base_state()
        np.testing.assert_allclose(pos, [1.0, -2.0, 0.7], atol=1e-6)  # PyBullet: float32 inside
        np.testing.assert_allclose(rpy, [0.1, -0.2, 2.5], atol=1e-6)
        np.testing.assert_allclose(np.concatenate([lin, ang]), 0.0, atol=1e-12)


def test_a_wrong_wheel_joint_name_names_the_key(flat_world, jackal_cfg):
    bad = to_object("robot", {**jackal_cfg.__dict__, "wheel_joints_left": ["front_left_wheel", "left_wheel_9"]})
    with pytest.raises(ConfigError, match=r"robot\.wheel_joints_left: joint 'left_wheel_9' is not in"):
        PybulletScene(flat_world, bad)
    bad = to_object("robot", {**jackal_cfg.__dict__, "wheel_joints_right": ["chassis"]})
    with pytest.raises(ConfigError, match=r"robot\.wheel_joints_right"):
        PybulletScene(flat_world, bad)


def test_urdf_specs_resolve_or_name_the_key():
    assert resolve_urdf("package:urdf/jackal.urdf").name == "jackal.urdf"
    assert resolve_urdf("pybullet_data:husky/husky.urdf").is_file()
    with pytest.raises(ConfigError, match=r"robot\.urdf: 'package:urdf/nope\.urdf'"):
        resolve_urdf("package:urdf/nope.urdf")


def test_rocker_differential_keeps_the_body_at_the_mean_rocker_pitch():
    """Lift the left front wheel onto a step: the left rocker tilts, the body pitches by half of it."""
    robot = to_object("robot", "rocker_bogie")
    world = World("flat", Terrain(np.zeros((21, 21)), 10.0, 10.0), [box_obstacle((0.35, 0.3, 0.075), (0.3, 0.2, 0.15))])
    with PybulletScene(world, robot) as scene:
        c, body = scene.client, scene.robot_id
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        pb.setPhysicsEngineParameter(fixedTimeStep=1 / 60, numSolverIterations=20, physicsClientId=c)
        scene.set_pose([0.0, 0.0, robot.base_height + 0.2], [0.0, 0.0, 0.0])
        pb.setJointMotorControlArray(
            body,
            list(scene.wheel_indices),
            pb.VELOCITY_CONTROL,
            targetVelocities=[0.0] * 6,
            forces=[50.0] * 6,
            physicsClientId=c,
        )
        for _ in range(240):
            pb.stepSimulation(physicsClientId=c)
        _, rpy, _, _ = scene.base_state()
        q_left = pb.getJointState(body, scene.joints["left_rocker"][0], physicsClientId=c)[0]
        q_right = pb.getJointState(body, scene.joints["right_rocker"][0], physicsClientId=c)[0]
        left_rocker_pitch, right_rocker_pitch = rpy[1] + q_left, rpy[1] + q_right
        assert left_rocker_pitch < -math.radians(10)  # the left rocker points nose up (negative pitch) ...
        assert right_rocker_pitch == pytest.approx(0.0, abs=math.radians(1))  # ... the right one stays level
        assert rpy[1] == pytest.approx(0.5 * (left_rocker_pitch + right_rocker_pitch), abs=math.radians(0.5))
        assert q_left == pytest.approx(-q_right, abs=1e-3)
