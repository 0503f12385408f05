"""The slope shield's hazard cameras (eval.shield.cameras): their poses, what they map, their noise and config."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diana_lab.config import ConfigError, compose, to_object
from diana_lab.config.evaluation import ShieldCameraConfig, ShieldConfig
from diana_lab.core.rotations import rpy_matrix
from diana_lab.evaluation.shield_cameras import ShieldCameras, turned_attitude
from diana_lab.shield import ShieldSettings, SlopeShield

ROBOT = to_object("robot", "jackal")
RING = [ShieldCameraConfig(yaw_deg=yaw, width=64, height=48) for yaw in (0.0, 90.0, 180.0, -90.0)]


def shield() -> SlopeShield:
    return SlopeShield(ShieldSettings.from_config(ShieldConfig(enabled=True, relief=True, min_range=1.0), ROBOT))


def sensor_cfg(noise: str = "none"):
    return to_object("sensor", compose(["sensor=depth_camera", f"sensor.noise={noise}"]).sensor)


@pytest.mark.parametrize("yaw", [0.0, 90.0, -135.0, 180.0])
def test_a_turned_camera_is_the_body_turned_about_its_own_up_axis(yaw):
    rpy = np.array([0.2, -0.3, 1.1])
    a = math.radians(yaw)
    turn = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    np.testing.assert_allclose(rpy_matrix(turned_attitude(rpy, yaw)), rpy_matrix(rpy) @ turn, atol=1e-12)


def known_quadrants(s: SlopeShield) -> dict[str, int]:
    m = s.memory
    iy, ix = np.divmod(np.flatnonzero(np.isfinite(m.mean_height)), m.n)
    xy = m.origin + (np.stack([ix, iy], axis=1) + 0.5) * m.cell_size
    near = np.hypot(*xy.T) < 4.0
    x, y = xy[near, 0], xy[near, 1]
    return {
        "ahead": int((x > 1.5).sum()),
        "behind": int((x < -1.5).sum()),
        "left": int((y > 1.5).sum()),
        "right": int((y < -1.5).sum()),
    }


def test_four_cameras_map_the_ground_all_round_the_rover_one_only_ahead(flat_world_small):
    position, rpy = np.array([0.0, 0.0, 0.098]), np.zeros(3)
    ring, front = shield(), shield()
    cams = ShieldCameras(RING, sensor_cfg(), flat_world_small)
    cams.reset(np.random.default_rng(0))
    cams.feed(ring, position, rpy)
    one = ShieldCameras(RING[:1], sensor_cfg(), flat_world_small)
    one.reset(np.random.default_rng(0))
    one.feed(front, position, rpy)
    all_round, ahead_only = known_quadrants(ring), known_quadrants(front)
    assert min(all_round.values()) > 50
    assert ahead_only["ahead"] > 50 and ahead_only["behind"] == 0
    heights = ring.memory.mean_height[np.isfinite(ring.memory.mean_height)]
    np.testing.assert_allclose(heights, 0.0, atol=1e-3)  # flat ground, where it is
    assert not ring.relief_crosses(position[:2], np.array([[3.0, 0.0], [-3.0, 0.0], [0.0, 3.0]])).any()


def test_the_cameras_take_the_sensors_noise_and_draw_it_from_the_generator_they_are_given(flat_world_small):
    maps = []
    for seed in (3, 3, 4):
        s = shield()
        cams = ShieldCameras(RING[:2], sensor_cfg("realistic"), flat_world_small)
        assert all(c.noise.active for c in cams.cameras)
        cams.reset(np.random.default_rng(seed))
        cams.feed(s, np.array([0.0, 0.0, 0.098]), np.zeros(3))
        maps.append(s.memory.mean_height.copy())
    np.testing.assert_array_equal(maps[0], maps[1])
    assert not np.array_equal(maps[0], maps[2], equal_nan=True)


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("eval.shield.cameras=[{width:0}]", r"eval.shield.cameras\[0\].width"),
        ("eval.shield.cameras=[{yaw_deg:0},{yaw_deg:270}]", r"eval.shield.cameras\[1\].yaw_deg"),
        ("eval.shield.cameras=[{mount_xyz:[0,1]}]", r"eval.shield.cameras\[0\].mount_xyz"),
        ("eval.shield.cameras=[{max_range:-1}]", r"eval.shield.cameras\[0\].max_range"),
        ("eval.shield.cameras=[{width:4000,height:4000}]", r"eval.shield.cameras\[0\]: expected at most"),
        ("eval.shield.relief_min_known=2", "eval.shield.relief_min_known"),
        ("eval.shield.relief_unseen_from=-0.5", "eval.shield.relief_unseen_from"),
    ],
)
def test_bad_camera_and_relief_settings_name_their_key(override, key):
    with pytest.raises(ConfigError, match=key):
        to_object("eval", compose([override]).eval)


def test_the_hazard_camera_preset_composes_the_reference_with_four_cameras_the_relief_check_and_the_route_rule():
    ev = to_object("eval", compose(["+experiment=reference_hazcams"]).eval)
    assert ev.shield.enabled and ev.shield.relief and ev.shield.detour_after == 2
    assert ev.shield.route and (ev.shield.route_tolerance, ev.shield.slope_cost_weight) == (1.0, 10.0)
    assert not to_object("eval", compose(["+experiment=reference"]).eval).shield.route  # v0.13 unchanged
    assert (ev.shield.relief_unseen_from, ev.shield.relief_min_known) == (0.8, 11)
    assert sorted(c.yaw_deg for c in ev.shield.cameras) == [-90.0, 0.0, 90.0, 180.0]
    assert ev.shield.limit_deg == to_object("eval", compose(["+experiment=reference"]).eval).shield.limit_deg


def test_body_frames_give_each_cameras_returns_where_it_looks_in_the_rover_frame(flat_world_small):
    cams = ShieldCameras(RING, sensor_cfg(), flat_world_small)
    frames = cams.body_frames(np.array([0.0, 0.0, 0.098]), np.zeros(3))
    (front, front_mount), (left, left_mount), (back, _), (right, right_mount) = frames
    np.testing.assert_allclose(front_mount, [0.2, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(left_mount, [0.0, 0.2, 1.0], atol=1e-12)
    np.testing.assert_allclose(right_mount, [0.0, -0.2, 1.0], atol=1e-12)
    assert np.median(front[:, 0]) > 1.0 and np.median(back[:, 0]) < -1.0
    assert np.median(left[:, 1]) > 1.0 and np.median(right[:, 1]) < -1.0
    np.testing.assert_allclose(np.concatenate([f for f, _ in frames])[:, 2], -0.098, atol=1e-3)  # the ground
