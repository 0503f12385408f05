import math

import numpy as np
import pytest

from diana_lab.config import ConfigError, to_object
from diana_lab.envs.action_spaces import ActionError, WaypointMapping, disc_to_square, square_to_disc


def test_concentric_mapping_covers_the_disc_and_inverts():
    rng = np.random.default_rng(0)
    a = rng.uniform(-1, 1, size=(20000, 2))
    p = square_to_disc(a)
    r = np.hypot(p[:, 0], p[:, 1])
    assert r.max() <= 1.0 + 1e-12
    np.testing.assert_allclose(disc_to_square(p), a, atol=1e-9)
    # uniform in the square -> uniform in the disc: area fractions match (no squashing)
    assert np.mean(r < 0.5) == pytest.approx(0.25, abs=0.01)
    angles = np.arctan2(p[:, 1], p[:, 0])
    hist, _ = np.histogram(angles, bins=8, range=(-math.pi, math.pi))
    assert hist.min() > 0.9 * hist.mean()
    # every point of the disc is reached by some action
    q = rng.uniform(-1, 1, size=(5000, 2))
    q = q[np.hypot(q[:, 0], q[:, 1]) <= 1]
    back = disc_to_square(q)
    assert np.abs(back).max() <= 1 + 1e-9
    np.testing.assert_allclose(square_to_disc(back), q, atol=1e-9)


def test_square_and_circle_extents():
    square = WaypointMapping(to_object("action_space", "square"))
    circle = WaypointMapping(to_object("action_space", "circle"))
    np.testing.assert_allclose(square.offset(np.array([1.0, 1.0]), 0.0), [3.5, 3.5])
    assert np.hypot(*circle.offset(np.array([1.0, 1.0]), 0.0)) == pytest.approx(4.0)
    assert np.hypot(*circle.offset(np.array([1.0, 0.0]), 0.0)) == pytest.approx(4.0)


def test_rover_and_world_frames():
    rover = WaypointMapping(to_object("action_space", {"name": "square", "shape": "square", "frame": "rover"}))
    world = WaypointMapping(to_object("action_space", {"name": "square", "shape": "square", "frame": "world"}))
    np.testing.assert_allclose(rover.offset(np.array([1.0, 0.0]), math.pi / 2), [0.0, 3.5], atol=1e-12)
    np.testing.assert_allclose(world.offset(np.array([1.0, 0.0]), math.pi / 2), [3.5, 0.0], atol=1e-12)
    for mapping in (rover, world):
        for yaw in (0.0, 1.0, -2.5):
            offset = np.array([1.2, -2.0])
            np.testing.assert_allclose(mapping.offset(mapping.action_for(offset, yaw), yaw), offset, atol=1e-9)


@pytest.mark.parametrize("bad", [[np.nan, 0.0], [0.0, np.inf], [1.0], [[1.0, 2.0]]])
def test_bad_actions_raise(bad):
    mapping = WaypointMapping(to_object("action_space", "square"))
    with pytest.raises(ActionError, match="action"):
        mapping.offset(np.array(bad), 0.0)


def test_huge_actions_are_clipped_to_the_shape():
    mapping = WaypointMapping(to_object("action_space", "circle"))
    assert np.hypot(*mapping.offset(np.array([1e9, -1e9]), 0.3)) == pytest.approx(4.0)


def discrete(**kwargs) -> WaypointMapping:
    return WaypointMapping(to_object("action_space", {"name": "discrete", "shape": "discrete", **kwargs}))


def test_discrete_candidates_are_bearings_times_distances_inside_the_square():
    mapping = WaypointMapping(to_object("action_space", "discrete"))
    table = mapping.candidates
    assert mapping.space.n == len(table) == 16 * 3 and table.shape == (48, 2)
    np.testing.assert_allclose(table[:3], [[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])  # straight ahead first
    np.testing.assert_allclose(table[3 * 4 + 1], [0.0, 2.0], atol=1e-12)  # heading 4 of 16: left, 2 m
    np.testing.assert_allclose(np.hypot(*table.T), np.tile([1.0, 2.0, 3.0], 16))
    assert np.abs(table).max() <= 3.5 and np.hypot(*table.T).max() <= 4.0  # the paper's square and disc
    assert mapping.extent == 3.0
    with pytest.raises(ValueError):
        table[0, 0] = 9.0  # the table is shared with every step: read-only
    with pytest.raises(ValueError, match="only a discrete"):
        _ = WaypointMapping(to_object("action_space", "square")).candidates


@pytest.mark.parametrize("frame", ["rover", "world"])
def test_discrete_offsets_turn_with_the_frame_and_invert(frame):
    mapping = discrete(frame=frame, headings=8, distances=[1.5, 3.0])
    yaw = math.pi / 2
    want = [0.0, 3.0] if frame == "rover" else [3.0, 0.0]
    np.testing.assert_allclose(mapping.offset(1, yaw), want, atol=1e-12)  # heading 0, 3 m
    for action in (0, np.int64(5), np.array(7), np.array([9], dtype=np.int32)):
        assert mapping.offset(action, 0.3).shape == (2,)
    for yaw in (0.0, 1.0, -2.5):
        for k in range(mapping.space.n):
            got = mapping.action_for(mapping.offset(k, yaw), yaw)
            assert got.dtype == np.int64 and got.shape == () and int(got) == k
            assert mapping.space.contains(got)


def test_discrete_action_for_picks_the_nearest_candidate_and_breaks_ties_low():
    mapping = discrete(headings=4, distances=[1.0, 2.0])  # 0: (1,0) 1: (2,0) 2: (0,1) 3: (0,2) ...
    assert int(mapping.action_for(np.array([1.8, 0.3]), 0.0)) == 1
    assert int(mapping.action_for(np.array([0.2, 2.6]), 0.0)) == 3
    assert int(mapping.action_for(np.array([40.0, 0.1]), 0.0)) == 1  # far: the farthest candidate that way
    assert int(mapping.action_for(np.zeros(2), 0.7)) == 0  # 1 m from every first-ring candidate
    assert int(mapping.action_for(np.array([1.5, 0.0]), 0.0)) == 0  # halfway between rings
    assert int(mapping.action_for(np.array([0.5, 0.5]), 0.0)) == 0  # between headings


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        (48, "outside"),
        (-1, "outside"),
        (2.0, "integer"),
        (np.float32(3), "integer"),
        (np.nan, "integer"),
        (True, "integer"),
        (np.array([1, 2]), "integer"),
        (np.array([0.5, 0.0]), "integer"),
    ],
)
def test_bad_discrete_actions_raise(bad, match):
    mapping = WaypointMapping(to_object("action_space", "discrete"))
    with pytest.raises(ActionError, match=match):
        mapping.offset(bad, 0.0)


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ({"size": 0.0}, "action_space.size"),
        ({"radius": -1.0}, "action_space.radius"),
        ({"shape": "hexagon"}, "action_space.shape"),
        ({"frame": "body"}, "action_space.frame"),
        ({"shape": "discrete", "headings": 1}, "action_space.headings"),
        ({"shape": "discrete", "headings": 0}, "action_space.headings"),
        ({"shape": "discrete", "distances": []}, "action_space.distances"),
        ({"shape": "discrete", "distances": [0.0, 1.0]}, "action_space.distances[0]"),
        ({"shape": "discrete", "distances": [1.0, 3.6]}, "action_space.distances[1]"),  # outside the 7 m square
        ({"shape": "discrete", "size": 4.0, "distances": [1.0, 2.5]}, "action_space.distances[1]"),
        ({"shape": "discrete", "distances": [2.0, 1.0]}, "action_space.distances"),
        ({"shape": "discrete", "distances": [1.0, 1.0]}, "action_space.distances"),
        ({"shape": "discrete", "min_distance": 0.5}, "action_space.min_distance"),
    ],
)
def test_bad_action_space_configs(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.").replace("[", r"\[").replace("]", r"\]")):
        to_object("action_space", {"name": "x", "shape": "square", **override})
