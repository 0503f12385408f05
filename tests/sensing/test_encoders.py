"""Encoders: always finite and inside their Box (real mars_yard world), and they mean what they say."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from diana_lab.config.sensing import ElevationMapConfig, PointsConfig
from diana_lab.sensing.encoders import NO_RETURN, UNKNOWN_HEIGHT
from tests.sensing.conftest import box, make_sensor, plane_world

ENCODINGS = ("depth_image", "elevation_map", "points")


def _random_poses(world, n, rng):
    x0, x1, y0, y1 = world.bounds
    for _ in range(n):
        x, y = rng.uniform(x0 + 2, x1 - 2), rng.uniform(y0 + 2, y1 - 2)
        z = float(world.height(x, y)) + rng.uniform(0.05, 0.3)
        yield np.array([x, y, z]), np.array([*rng.normal(0.0, 0.15, 2), rng.uniform(-np.pi, np.pi)])


@pytest.mark.parametrize("option", ["depth_camera", "lidar3d"])
@pytest.mark.parametrize("encoding", ENCODINGS)
def test_encodings_stay_inside_their_space_on_mars_yard(mars_yard, option, encoding):
    rng = np.random.default_rng(11)
    sensor = make_sensor(option, mars_yard, encoding=encoding, noise="harsh")
    sensor.reset(rng)
    space = sensor.observation_space
    assert space.dtype == np.float32
    for position, rpy in _random_poses(mars_yard, 12, rng):
        obs = sensor.observe(position, rpy)
        assert obs.dtype == np.float32 and obs.shape == space.shape
        assert np.isfinite(obs).all()
        assert space.contains(obs)


def test_depth_image_is_depth_over_max_range_with_no_return_at_one():
    world = plane_world(0.0)
    cam = make_sensor("depth_camera", world)
    frame = cam.capture(np.array([0.0, 0.0, 0.1]), np.zeros(3))
    obs = cam.encode(frame)
    assert obs.shape == (1, 48, 64)
    np.testing.assert_allclose(obs[0][frame.valid], frame.depth[frame.valid] / cam.cfg.max_range, rtol=1e-6)
    assert np.all(obs[0][~frame.valid] == NO_RETURN)
    assert "points" not in frame.__dict__  # the depth image never needed the point cloud


def test_elevation_map_shows_ground_and_an_obstacle_in_the_right_cells():
    em = ElevationMapConfig(
        cell_size=0.25, extent_forward=8.0, extent_back=2.0, extent_side=5.0, height_clip=1.0, voxel_size=0.02
    )
    top = 0.3  # lower than the camera (0.348 m above the ground), so the camera sees the box's top edge
    world = plane_world(0.0, obstacles=[box((3.1, 1.05, 0.0), (3.6, 1.45, top))])
    cam = make_sensor("depth_camera", world, encoding="elevation_map", elevation_map=em)
    base = 0.098

    def encoded(h):
        return (h - base + 1.0) / 2.0

    for rpy in ([0.0, 0.0, 0.0], [0.0, 0.12, 0.0], [-0.1, 0.0, 0.0]):  # levelled: tilt does not matter
        obs = cam.observe(np.array([0.0, 0.0, base]), np.array(rpy))
        assert obs.shape == (2, 40, 40)
        height, known = obs
        assert known.sum() > 100 and np.all((known == 0) | (known == 1))
        np.testing.assert_array_equal(height[known == 0], UNKNOWN_HEIGHT)
        # the box: x 3.1..3.6 -> rows (8 - 3.6)/0.25 .. (8 - 3.1)/0.25 = 17..19; y 1.05..1.45 -> cols 14..15
        np.testing.assert_allclose(height[17:20, 14:16].max(), encoded(top), atol=0.01)
        ground = known.astype(bool)
        ground[16:21, 13:17] = False  # the box and its shadow's edge
        assert ground.sum() > 100
        np.testing.assert_allclose(height[ground], encoded(0.0), atol=0.01)


def test_elevation_map_outlier_removal_runs():
    em = dataclasses.replace(ElevationMapConfig(), outlier_removal=True)
    cam = make_sensor("depth_camera", plane_world(0.0), encoding="elevation_map", elevation_map=em, noise="harsh")
    obs = cam.observe(np.array([0.0, 0.0, 0.1]), np.zeros(3))
    assert cam.observation_space.contains(obs) and obs[1].sum() > 50


@pytest.mark.parametrize("method", ["voxel", "fps"])
def test_points_encoding_is_a_padded_masked_set(method):
    world = plane_world(0.0, obstacles=[box((3.0, -0.5, 0.0), (3.5, 0.5, 0.5))])
    pts_cfg = PointsConfig(n_points=256, method=method, voxel_size=0.1)
    sensor = make_sensor("depth_camera", world, encoding="points", points=pts_cfg)
    frame = sensor.capture(np.array([0.0, 0.0, 0.1]), np.zeros(3))
    obs = sensor.encode(frame)
    assert obs.shape == (256, 4) and obs[:, 3].sum() == 256  # plenty of points: no padding needed
    xyz = obs[:, :3] * sensor.encoder.scale
    assert np.all(xyz[:, 0] > 0) and np.any(np.abs(xyz[:, 0] - 3.0) < 0.06)  # the box face is in the set
    # few points: padded with zero rows and mask 0
    sky = make_sensor(
        "depth_camera", world, encoding="points", points=pts_cfg, mount_pitch_deg=-24.0
    )  # only the bottom rows see ground
    few = sky.observe(np.array([0.0, 0.0, 0.1]), np.zeros(3))
    m = int(few[:, 3].sum())
    assert 0 < m < 256
    np.testing.assert_array_equal(few[m:], 0.0)
    assert sky.observation_space.contains(few)
