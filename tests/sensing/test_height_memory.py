"""The ``elevation_map`` memory: a world-frame map fused over the episode, read as rover-centred windows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diana_lab.config import ConfigError
from diana_lab.config.sensing import ElevationMapConfig
from diana_lab.core.height_memory import HeightMemory
from tests.sensing.conftest import box, make_sensor, plane_world

MEMORY = ElevationMapConfig(
    cell_size=0.25, extent_forward=6.0, extent_back=6.0, extent_side=6.0, voxel_size=0.0, memory=True
)


def _window_at(memory: HeightMemory, ahead: float, left: float) -> tuple[int, int]:
    """The window cell holding a point ``ahead`` m in front and ``left`` m to the left of the rover."""
    return int((6.0 - ahead) // memory.cell_size), int((6.0 - left) // memory.cell_size)


def test_the_window_turns_with_the_heading_and_the_latest_frame_wins():
    m = HeightMemory(0.25, 20.0, 48, 48, 6.0, 6.0)
    m.update(np.array([[3.1, 0.1, 0.7]]), centre=np.zeros(2))  # 3 m east of the origin, 0.7 m high
    east = m.window(np.zeros(2), 0.0, base_z=0.2)
    assert east[_window_at(m, 3.1, 0.1)] == pytest.approx(0.5)  # relative to the base
    assert np.isnan(east).sum() == east.size - 1  # everything else unknown
    north = m.window(np.zeros(2), math.pi / 2, base_z=0.2)  # facing north, east is to the right
    assert north[_window_at(m, 0.1, -3.1)] == pytest.approx(0.5)
    m.update(np.array([[3.1, 0.1, 0.1]]), centre=np.zeros(2))  # seen again lower: dust gone, latest wins
    assert m.window(np.zeros(2), 0.0, 0.2)[_window_at(m, 3.1, 0.1)] == pytest.approx(-0.1)
    m.update(np.array([[30.0, 0.0, 5.0]]), centre=np.zeros(2))  # off the 20 m map: dropped, no error
    assert np.isfinite(m.height).sum() == 1
    assert np.isnan(m.window(np.array([26.0, 0.0]), 0.0, 0.0)).all()  # a window off the map is unknown
    m.reset()
    assert np.isnan(m.window(np.zeros(2), 0.0, 0.0)).all()


def test_a_box_seen_once_stays_on_the_map_after_the_camera_turns_away():
    world = plane_world(0.0, obstacles=[box((3.0, -0.5, 0.0), (3.5, 0.5, 0.3))])
    cam = make_sensor("depth_camera", world, encoding="elevation_map", elevation_map=MEMORY)
    plain = make_sensor(
        "depth_camera",
        world,
        encoding="elevation_map",
        elevation_map=ElevationMapConfig(**{**vars(MEMORY), "memory": False}),
    )
    rng = np.random.default_rng(0)
    cam.reset(rng)
    position = np.array([0.0, 0.0, 0.1])
    facing = cam.observe(position, np.zeros(3))
    row, col = _window_at(cam.encoder.memory, 3.05, 0.0)
    assert facing[1, row, col] == 1.0 and facing[0, row, col] > 0.5  # the box's front face, above the base
    turned = cam.observe(position, np.array([0.0, 0.0, math.pi]))  # now the box is 3 m behind
    back_row, back_col = _window_at(cam.encoder.memory, -3.05, 0.0)
    assert turned[1, back_row, back_col] == 1.0 and turned[0, back_row, back_col] == facing[0, row, col]
    # without memory the rover turned away knows nothing behind it
    plain.reset(rng)
    plain.observe(position, np.zeros(3))
    assert plain.observe(position, np.array([0.0, 0.0, math.pi]))[1, back_row, back_col] == 0.0
    # a new episode starts with an empty map
    cam.reset(rng)
    assert cam.observe(position, np.array([0.0, 0.0, math.pi]))[1, back_row, back_col] == 0.0


def test_the_map_stays_inside_the_space_over_a_drive_on_mars_yard(mars_yard):
    lidar = make_sensor("lidar3d", mars_yard, encoding="elevation_map", elevation_map=MEMORY, noise="harsh")
    lidar.reset(np.random.default_rng(3))
    x0, _, y0, _ = mars_yard.bounds
    known = []
    for i in range(12):
        x, y = x0 + 10 + 1.5 * i, y0 + 10 + 0.5 * i
        obs = lidar.observe(np.array([x, y, float(mars_yard.height(x, y)) + 0.1]), np.array([0.05, -0.05, 0.3 * i]))
        assert lidar.observation_space.contains(obs) and np.isfinite(obs).all()
        known.append(obs[1].mean())
    assert known[-1] > known[0]  # the map fills in as the rover drives


def test_bad_memory_settings_name_the_key():
    with pytest.raises(ConfigError, match=r"sensor\.elevation_map\.memory_radius"):
        ElevationMapConfig(memory=True, memory_radius=0.0)
    with pytest.raises(ConfigError, match=r"sensor\.elevation_map\.memory"):
        ElevationMapConfig(memory="yes")


def _mapped(fn, half: float = 5.0, cell: float = 0.2) -> HeightMemory:
    """A memory with 0.2 m cells that has seen ``z = fn(x, y)`` at every cell centre within ``half`` m."""
    m = HeightMemory(cell, 10.0, 1, 1, 0.0, 0.0)
    m.update(np.zeros((0, 3)), centre=np.zeros(2))  # centres the map on the origin
    g = np.arange(-half, half, cell) + cell / 2
    x, y = np.meshgrid(g, g)
    m.update(np.column_stack([x.ravel(), y.ravel(), fn(x, y).ravel()]), centre=np.zeros(2))
    return m


def test_roughness_is_nil_on_any_plane_and_a_rock_does_not_make_smooth_ground_rough():
    tilted = _mapped(lambda x, y: 0.4 * x - 0.2 * y)  # a 24 deg slope
    assert tilted.roughness_near(0.0, 0.0, 8) < 1e-5  # float32 heights: rounding only
    rock = _mapped(lambda x, y: np.where((np.abs(x - 1.0) < 0.2) & (np.abs(y) < 0.2), 0.3, 0.0))
    assert rock.roughness_near(0.0, 0.0, 8) < 1e-5  # 1-4 of ~300 blocks: the median ignores it


def test_roughness_counts_relief_a_block_wide_and_damps_noise_a_cell_wide():
    """Blocks of 2 x 2 cells: 2 cm of noise from cell to cell (range noise on a flat floor) mostly averages out,
    4 cm waves 1.1-1.3 m long (relief) do not."""
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 0.02, (50, 50))
    cell = lambda x, y: (((x + 5.0) / 0.2).astype(int), ((y + 5.0) / 0.2).astype(int))  # noqa: E731
    noisy = _mapped(lambda x, y: noise[cell(x, y)[1], cell(x, y)[0]])
    blocky = _mapped(lambda x, y: 0.04 * np.sin(2 * np.pi * x / 1.1) * np.sin(2 * np.pi * y / 1.3))
    assert noisy.roughness_near(0.0, 0.0, 8) < 0.01 < blocky.roughness_near(0.0, 0.0, 8)
    assert noisy.roughness_near(0.0, 0.0, 2) != noisy.roughness_near(0.0, 0.0, 8)  # its own window


def test_roughness_needs_enough_known_ground_around_the_point():
    m = HeightMemory(0.2, 10.0, 1, 1, 0.0, 0.0)
    assert math.isnan(m.roughness_near(0.0, 0.0, 8))  # nothing mapped yet
    m.update(np.array([[0.1, 0.1, 0.0], [0.3, 0.1, 0.0], [0.1, 0.3, 0.0]]), centre=np.zeros(2))
    assert math.isnan(m.roughness_near(0.0, 0.0, 8))  # one block known, none with its 4 neighbours
    plane = _mapped(lambda x, y: 0.0 * x, half=2.0)  # 20 x 20 cells
    assert plane.roughness_near(0.0, 0.0, 8) == 0.0
    assert math.isnan(plane.roughness_near(0.0, 0.0, 8, min_blocks=200))
    assert math.isnan(plane.roughness_near(30.0, 0.0, 8))  # off the map
    with pytest.raises(ValueError, match="reach >= 1"):
        plane.roughness_near(0.0, 0.0, 0)
