"""The map's stopped-drive channel: HazardMemory, its config key and the encoders that carry it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diana_lab import config as C
from diana_lab.core.hazard_memory import HazardMemory
from diana_lab.core.validation import ConfigError
from diana_lab.training.envs import env_config, make_env

# a 9 x 9 window of 0.5 m cells round the rover (the rover at the centre cell)
GEOMETRY = {"cell_size": 0.5, "rows": 9, "cols": 9, "extent_forward": 2.25, "extent_side": 2.25}


def _memory(radius: float = 0.6) -> HazardMemory:
    return HazardMemory(radius, **GEOMETRY)


def _grid(memory: HazardMemory, x: float, y: float, yaw: float) -> np.ndarray:
    return memory.window(x, y, yaw).reshape(memory.shape)


def test_cells_within_the_radius_of_a_spot_are_marked_and_no_others() -> None:
    memory = _memory(0.6)
    memory.mark((11.5, 20.0))  # 1.5 m ahead of a rover at (10, 20) facing +x
    grid = _grid(memory, 10.0, 20.0, 0.0)
    # cell centres (heading frame): x = 2.25 - (row + 0.5) * 0.5, y = 2.25 - (col + 0.5) * 0.5
    rows, cols = np.nonzero(grid)
    centres = np.stack([2.25 - (rows + 0.5) * 0.5, 2.25 - (cols + 0.5) * 0.5], axis=1)
    assert len(rows) == 5  # the spot's own cell and its four edge neighbours (0.5 m away); diagonals are 0.71 m
    assert np.all(np.hypot(centres[:, 0] - 1.5, centres[:, 1]) <= 0.6)
    assert grid[1, 4] == 1.0 and grid[4, 4] == 0.0  # 1.5 m ahead, not under the rover
    assert grid.dtype == np.float32 and set(np.unique(grid)) == {0.0, 1.0}


def test_the_window_turns_with_the_rover_and_forgets_at_reset() -> None:
    memory = _memory(0.3)
    memory.mark(np.array([0.0, 2.0, 0.7]))  # a 3-D point: its xy is kept
    facing_spot = _grid(memory, 0.0, 0.0, math.pi / 2)  # heading +y: the spot 2 m dead ahead
    facing_away = _grid(memory, 0.0, 0.0, -math.pi / 2)  # heading -y: the spot 2 m behind
    assert facing_spot[0, 4] == 1.0 and facing_spot.sum() == 1.0
    assert facing_away[8, 4] == 1.0 and facing_away.sum() == 1.0
    np.testing.assert_array_equal(memory.spots, [[0.0, 2.0]])
    memory.reset()
    assert memory.spots.shape == (0, 2) and not _grid(memory, 0.0, 0.0, 0.0).any()


@pytest.mark.parametrize("bad", [(np.nan, 1.0), (1.0,), "here"])
def test_a_spot_that_is_not_a_finite_point_is_refused(bad) -> None:
    with pytest.raises(ValueError, match="expected a finite world"):
        _memory().mark(bad)


def test_a_radius_that_is_not_positive_is_refused() -> None:
    with pytest.raises(ValueError, match="positive, finite radius"):
        HazardMemory(0.0, **GEOMETRY)


def test_the_config_key_is_checked_and_needs_the_elevation_map() -> None:
    with pytest.raises(ConfigError, match=r"sensor\.elevation_map\.hazard_radius"):
        C.to_object("sensor", C.compose(["sensor.elevation_map.hazard_radius=-1"]).sensor)
    with pytest.raises(ConfigError, match=r"hazard_radius=0.5.*sensor.encoding=depth_image"):
        C.to_object("sensor", C.compose(["sensor=depth_camera", "sensor.elevation_map.hazard_radius=0.5"]).sensor)


def test_the_env_shows_where_its_drives_were_stopped() -> None:
    """The main command's env with the channel: three channels, empty at reset, marked round the spot a halted
    drive reported, from the observation after that step."""
    cfg = C.compose(["sensor.elevation_map.hazard_radius=0.75", "robot.tilt_guard_deg=10"])
    env = make_env(env_config(cfg))
    try:
        obs, _ = env.reset(seed=3)
        assert obs["elevation_map"].shape[0] == 3 and not obs["elevation_map"][2].any()
        rng = np.random.default_rng(0)
        for _ in range(200):
            obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
            hazard = env.last_waypoint.hazard_xy
            if hazard is not None and not (terminated or truncated):
                break
            if terminated or truncated:
                obs, _ = env.reset()
        else:
            pytest.fail("no drive was stopped in 200 steps")
        spots = env.sensor.encoder.hazards.spots
        np.testing.assert_array_equal(spots[-1], hazard[:2])
        assert obs["elevation_map"][2].any()
    finally:
        env.close()
