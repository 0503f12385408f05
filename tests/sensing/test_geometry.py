"""Ray-cast geometry: analytic depths, obstacles at their true distance, frames, and rays without returns."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from diana_lab.core.rotations import leveling_matrix, rpy_matrix
from diana_lab.sensing.camera import pinhole_pattern
from tests.sensing.conftest import box, make_sensor, plane_world


def _analytic_plane_ranges(cam, position, rpy, plane_z):
    """Ranges to the plane z = plane_z from an independent construction of the camera rays (scipy)."""
    c = cam.cfg
    pattern = pinhole_pattern(c.width, c.height, c.hfov_deg, c.vfov_deg).reshape(-1, 3)
    body = Rotation.from_euler("ZYX", [rpy[2], rpy[1], rpy[0]])
    mount = Rotation.from_euler("y", c.mount_pitch_deg, degrees=True)
    d = (body * mount).apply(pattern)
    origin = np.asarray(position) + body.apply(c.mount_xyz)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (plane_z - origin[2]) / d[:, 2]
    t[~(t > 0)] = np.inf
    return t.reshape(c.height, c.width), pattern[:, 0].reshape(c.height, c.width)


@pytest.mark.parametrize("rpy", [(0.0, 0.0, 0.0), (0.1, -0.15, 2.0)])
def test_depth_of_a_flat_plane_is_analytic_for_every_pixel(rpy):
    plane_z = 1.25
    world = plane_world(plane_z)
    cam = make_sensor("depth_camera", world)
    position = np.array([1.0, -2.0, plane_z + 0.098])
    frame = cam.capture(position, np.array(rpy))
    t, cos = _analytic_plane_ranges(cam, position, rpy, plane_z)
    in_range = (t >= cam.cfg.min_range) & (t <= cam.cfg.max_range)
    unsure = np.abs(t - cam.cfg.max_range) < 1e-3  # float32 may put these on either side of the limit
    assert in_range.sum() > 1000 and (~in_range).sum() > 100  # ground and "sky" both in view
    np.testing.assert_array_equal(frame.valid[~unsure], in_range[~unsure])
    both = in_range & frame.valid
    np.testing.assert_allclose(frame.ranges[both], t[both], atol=1e-3, rtol=0)
    np.testing.assert_allclose(frame.depth[both], (t * cos)[both], atol=1e-3, rtol=0)
    assert frame.ranges.dtype == np.float32 and frame.ranges.shape == (48, 64)
    assert np.isnan(frame.depth[~frame.valid]).all()


def test_box_in_front_appears_at_its_true_distance():
    face_x = 3.0
    world = plane_world(0.0, obstacles=[box((face_x, -1.0, 0.0), (face_x + 1.0, 1.0, 2.0))])
    cam = make_sensor("depth_camera", world, mount_pitch_deg=0.0)
    frame = cam.capture(np.array([0.0, 0.0, 0.098]), np.zeros(3))
    on_face = np.abs(frame.points[:, 0] - face_x) < 1e-3
    assert on_face.sum() > 200
    # every pixel that sees the face has depth = distance from the camera to the face along its axis
    depth_on_face = frame.depth[frame.valid].reshape(-1)[on_face]
    np.testing.assert_allclose(depth_on_face, face_x - cam.cfg.mount_xyz[0], atol=1e-4)
    centre = frame.ranges[22:26, 30:34]
    assert np.all(np.abs(centre - (face_x - 0.2)) < 0.01)

    lidar = make_sensor("lidar3d", world)
    lf = lidar.capture(np.array([0.0, 0.0, 0.098]), np.zeros(3))
    pts = lf.points
    ahead = (np.abs(pts[:, 1]) < 0.5) & (pts[:, 2] > 0.2)
    assert ahead.any()
    np.testing.assert_allclose(pts[ahead, 0], face_x, atol=1e-3)


def test_rpy_matrix_matches_scipy():
    rng = np.random.default_rng(0)
    for rpy in rng.uniform(-math.pi, math.pi, (20, 3)):
        expected = Rotation.from_euler("ZYX", [rpy[2], rpy[1], rpy[0]]).as_matrix()
        np.testing.assert_allclose(rpy_matrix(rpy), expected, atol=1e-12)
        level = Rotation.from_euler("ZYX", [0.0, rpy[1], rpy[0]]).as_matrix()
        np.testing.assert_allclose(leveling_matrix(rpy), level, atol=1e-12)
    # positive pitch lowers the nose
    assert rpy_matrix((0.0, 0.3, 0.0))[2, 0] < 0


@pytest.mark.parametrize("option", ["depth_camera", "lidar3d"])
def test_points_are_in_the_rover_frame_for_any_roll_pitch_yaw(option):
    plane_z = -0.5
    world = plane_world(plane_z, obstacles=[box((4.0, 4.0, plane_z), (5.0, 5.0, plane_z + 1.0))])
    sensor = make_sensor(option, world)
    rng = np.random.default_rng(3)
    for _ in range(5):
        rpy = np.array([*rng.uniform(-0.3, 0.3, 2), rng.uniform(-math.pi, math.pi)])
        position = np.array([*rng.uniform(-3, 3, 2), plane_z + 0.3])
        frame = sensor.capture(position, rpy)
        world_pts = Rotation.from_euler("ZYX", rpy[::-1]).apply(frame.points) + position
        np.testing.assert_allclose(frame.points_world(), world_pts, atol=1e-5)
        on_box = (
            (world_pts[:, 0] > 3.999)
            & (world_pts[:, 0] < 5.001)
            & (world_pts[:, 1] > 3.999)
            & (world_pts[:, 1] < 5.001)
        )
        # everything hit is on the ground plane or on the box surface
        np.testing.assert_allclose(world_pts[~on_box, 2], plane_z, atol=1e-4)
        assert np.all(world_pts[on_box, 2] < plane_z + 1.0 + 1e-4)
        # and lies at the measured range from the sensor
        sensor_pos = rpy_matrix(rpy) @ np.asarray(sensor.cfg.mount_xyz) + position
        dist = np.linalg.norm(world_pts - sensor_pos, axis=1)
        np.testing.assert_allclose(dist, frame.ranges[frame.valid], atol=1e-4)


def test_rays_into_the_sky_return_nothing():
    world = plane_world(0.0)
    cam = make_sensor("depth_camera", world, mount_pitch_deg=-60.0)  # looking up
    frame = cam.capture(np.array([0.0, 0.0, 0.1]), np.zeros(3))
    assert np.isnan(frame.ranges).all() and len(frame.points) == 0
    np.testing.assert_array_equal(cam.encode(frame), 1.0)
    # beyond max range is no return either (not a hit at max range)
    short = make_sensor("depth_camera", world, max_range=1.0)
    f2 = short.capture(np.array([0.0, 0.0, 0.1]), np.zeros(3))
    assert np.nanmax(f2.ranges) <= 1.0 and np.isnan(f2.ranges).mean() > 0.3
    # and so is a hit closer than min range
    near = make_sensor("depth_camera", world, min_range=0.6)
    f3 = near.capture(np.array([0.0, 0.0, 0.1]), np.zeros(3))
    assert np.nanmin(f3.ranges) >= 0.6 and len(f3.points) == int(f3.valid.sum())
