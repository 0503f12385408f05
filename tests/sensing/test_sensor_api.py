"""Configs, composition, building, pickling into workers, and the PyBullet reference caster."""

from __future__ import annotations

import dataclasses
import pickle
from functools import cache

import numpy as np
import pytest
from omegaconf import OmegaConf

from diana_lab.config import CONF_DIR, ConfigError, build, compose, to_object
from diana_lab.sensing import DepthCamera, Lidar3d
from tests.sensing.conftest import box, make_sensor, plane_world

OPTIONS = sorted(p.stem for p in (CONF_DIR / "sensor").glob("*.yaml"))


@cache
def _composed(option: str):
    return compose([f"sensor={option}"]).sensor


def test_every_sensor_option_composes_builds_and_observes(flat_plane):
    assert {"depth_camera", "depth_camera_paper", "lidar3d"} <= set(OPTIONS)
    for option in OPTIONS:
        cfg = to_object("sensor", compose([f"sensor={option}"]).sensor)
        assert cfg.name == option
        sensor = build(cfg, flat_plane)
        assert isinstance(sensor, DepthCamera | Lidar3d)
        obs = sensor.observe(np.array([0.0, 0.0, 0.1]), np.zeros(3))
        assert sensor.observation_space.contains(obs)
    paper = to_object("sensor", "depth_camera_paper")
    assert (paper.width, paper.height) == (112, 112)


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        (["sensor.width=0"], "sensor.width"),
        (["sensor.height=-3"], "sensor.height"),
        (["sensor.min_range=10", "sensor.max_range=10"], "sensor.min_range"),
        (["sensor.min_range=5", "sensor.max_range=2"], "sensor.max_range"),
        (["sensor.hfov_deg=180"], "sensor.hfov_deg"),
        (["sensor.vfov_deg=0"], "sensor.vfov_deg"),
        (["sensor.encoding=voxels"], "sensor.encoding"),
        (["sensor.noise=terrible"], "sensor.noise"),
        (["sensor.noise_level=-1"], "sensor.noise_level"),
        (["sensor.mount_xyz=[0.0,0.0]"], "sensor.mount_xyz"),
        (["sensor.elevation_map.cell_size=0"], "sensor.elevation_map.cell_size"),
        (["sensor.points.n_points=0"], "sensor.points.n_points"),
        (["sensor.points.method=random"], "sensor.points.method"),
        (["sensor=lidar3d", "sensor.beams=0"], "sensor.beams"),
        (["sensor=lidar3d", "sensor.horizontal_resolution_deg=0"], "sensor.horizontal_resolution_deg"),
        (["sensor=lidar3d", "sensor.vfov_min_deg=20"], "sensor.vfov_min_deg"),
    ],
)
def test_bad_sensor_configs_name_the_key(overrides, key):
    option = next((o.split("=")[1] for o in overrides if o.startswith("sensor=")), "depth_camera")
    keys = [o.removeprefix("sensor.") for o in overrides if o.startswith("sensor.")]
    node = OmegaConf.merge(_composed(option), OmegaConf.from_dotlist(keys))  # = compose(overrides), faster
    with pytest.raises(ConfigError, match=key.replace(".", r"\.").replace("[", r"\[")):
        to_object("sensor", node)


def test_bad_override_is_caught_when_composing_too():
    with pytest.raises(ConfigError, match=r"sensor\.width: expected a positive integer, got 0"):
        to_object("sensor", compose(["sensor=depth_camera", "sensor.width=0"]).sensor)


def test_pickled_sensor_round_trips_and_still_works():
    world = plane_world(0.0, obstacles=[box((3.0, -1.0, 0.0), (4.0, 1.0, 1.0))])
    sensor = make_sensor("depth_camera", world, noise="realistic", encoding="elevation_map")
    pose = (np.array([0.0, 0.0, 0.1]), np.array([0.02, 0.0, 0.1]))
    sensor.reset(np.random.default_rng(5))
    first = sensor.observe(*pose)  # the open3d scene exists now, and must not be pickled
    clone = pickle.loads(pickle.dumps(sensor))
    assert clone.caster._scene is None
    sensor.reset(np.random.default_rng(5))
    clone.reset(np.random.default_rng(5))
    np.testing.assert_array_equal(clone.observe(*pose), sensor.observe(*pose))
    np.testing.assert_array_equal(clone.observe(*pose).shape, first.shape)


def test_pybullet_reference_casts_the_same_rays():
    from diana_lab.sensing.pybullet_reference import PyBulletRayCaster

    world = plane_world(0.0, size=20.0, obstacles=[box((3.0, -1.0, 0.0), (4.0, 1.0, 1.0))])
    sensor = make_sensor("depth_camera", world, mount_pitch_deg=5.0)
    pose = (np.array([0.0, 0.3, 0.1]), np.array([0.0, 0.05, 0.2]))
    origins, directions = sensor.rays_world(*pose)
    ours = sensor.capture(*pose).ranges.ravel()
    for terrain in ("mesh", "heightfield"):
        with PyBulletRayCaster(world, terrain=terrain) as ref:
            theirs = ref.cast(origins, directions, sensor.cfg.max_range)
        both = np.isfinite(theirs) & np.isfinite(ours)
        assert both.mean() > 0.5
        np.testing.assert_allclose(theirs[both], ours[both], atol=1e-3)


def test_camera_defaults_see_the_ground_from_one_to_eight_metres(flat_plane):
    cam = build(to_object("sensor", "depth_camera"), flat_plane)
    frame = cam.capture(np.array([0.0, 0.0, 0.098]), np.zeros(3))  # Jackal base height
    forward = frame.points[np.abs(frame.points[:, 1]) < 0.3, 0]
    assert forward.min() < 1.0 and forward.max() > 8.0
    assert dataclasses.asdict(cam.cfg)["nthreads"] == 1


def _cloud_by_numpy(frame) -> np.ndarray:
    """The definition of ``SensorFrame.points``: ``directions * range + mount`` in float32, valid rays in order."""
    r = frame.ranges.reshape(-1)
    keep = np.flatnonzero(~np.isnan(r))
    return frame.directions[keep] * r[keep][:, None] + frame.origin


@pytest.mark.parametrize("option", ["depth_camera", "lidar3d"])
@pytest.mark.parametrize("backend, noise", [("heightfield", "none"), ("open3d", "none"), ("heightfield", "realistic")])
def test_point_cloud_is_the_ranges_through_the_ray_pattern_bit_for_bit(option, backend, noise):
    # the heightfield caster writes the cloud while casting (no noise); otherwise the frame computes it
    from diana_lab.sim.terrain import Terrain
    from diana_lab.sim.world import World

    heights = np.random.default_rng(3).normal(0.0, 0.15, size=(41, 41))
    world = World("rough", Terrain(heights, 20.0, 20.0), [box((2.0, -0.5, -0.5), (2.6, 0.5, 0.6))])
    sensor = make_sensor(option, world, backend=backend, noise=noise)
    sensor.reset(np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for _ in range(20):
        pose = (np.array([*rng.uniform(-3.0, 3.0, 2), 0.4]), rng.uniform(-0.2, 0.2, 3) * [1, 1, 15])
        frame = sensor.capture(*pose)
        assert (frame.cloud is not None) == (backend == "heightfield" and noise == "none")
        expected = _cloud_by_numpy(frame)
        assert 0 < len(expected) < frame.ranges.size  # some returns, some rays without one
        assert frame.points.dtype == np.float32
        np.testing.assert_array_equal(frame.points, expected)
