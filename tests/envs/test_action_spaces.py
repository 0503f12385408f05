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


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ({"size": 0.0}, "action_space.size"),
        ({"radius": -1.0}, "action_space.radius"),
        ({"shape": "hexagon"}, "action_space.shape"),
        ({"frame": "body"}, "action_space.frame"),
    ],
)
def test_bad_action_space_configs(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        to_object("action_space", {"name": "x", "shape": "square", **override})
