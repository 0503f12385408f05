"""The depth camera's near-field raster: the ray marcher's very ranges (bit for bit), from fewer tests."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diana_lab.core.rotations import pitch_matrix, rpy_matrix
from diana_lab.sensing.camera import pinhole_pattern
from diana_lab.sensing.heightfield_cast import heightfield_for
from diana_lab.sensing.lidar import lidar_pattern
from diana_lab.sensing.pinhole import Pinhole
from diana_lab.sensing.pinhole_raster import DELTA, REACH_CELLS
from diana_lab.sensing.raycast import RayCaster
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import World
from tests.sensing.conftest import box, make_sensor, plane_world


def camera(width: int, height: int, hfov: float, vfov: float, pitch_deg: float) -> tuple[np.ndarray, Pinhole]:
    """A camera's rover-frame pixel rays (float32, as the caster keeps them) and its pinhole model."""
    mount = pitch_matrix(math.radians(pitch_deg))
    directions = (pinhole_pattern(width, height, hfov, vfov).reshape(-1, 3) @ mount.T).astype(np.float32)
    tan_h, tan_v = math.tan(math.radians(hfov) / 2), math.tan(math.radians(vfov) / 2)
    return directions, Pinhole(width, height, tan_h, tan_v, mount)


CAMERAS = {
    "d435_64x48": (64, 48, 87.0, 58.0, 22.0),  # the default depth camera
    "paper_112": (112, 112, 87.0, 58.0, 22.0),
    "looking_up": (40, 30, 70.0, 50.0, -25.0),
    "steep_down": (32, 24, 100.0, 80.0, 60.0),
}


def bumpy_world() -> World:
    """Steep random bumps on a non-square grid of non-square cells, and boxes near the sensor's path."""
    rng = np.random.default_rng(5)
    heights = np.cumsum(rng.normal(0.0, 0.08, (41, 57)), axis=1) + rng.normal(0.0, 0.05, (41, 57))
    obstacles = [box((1.0, -0.5, -1.0), (1.4, 0.3, 2.0)), box((-2.0, 1.0, -1.0), (-1.2, 1.3, 0.8), "post")]
    return World("bumpy", Terrain(heights, 11.2, 6.0), obstacles)  # 0.2 x 0.15 m cells


def poses(world: World, rng: np.random.Generator, n: int):
    """Sensors over the terrain (some low, some high, some near or off the map's edges), tilted any way."""
    x0, x1, y0, y1 = world.bounds
    for k in range(n):
        if k % 8 == 7:  # off the map or at its very edge
            xy = np.array([rng.choice([x0 - 1.0, x0 + 0.01, x1 - 0.01]), rng.uniform(y0, y1)])
        else:
            xy = rng.uniform([x0 + 0.3, y0 + 0.3], [x1 - 0.3, y1 - 0.3])
        ground = float(world.height(*np.clip(xy, [x0, y0], [x1, y1])))
        origin = np.array([*xy, ground + rng.choice([0.01, 0.3, 0.6, 3.0])])
        yield origin, rpy_matrix([rng.normal(0, 0.3), rng.normal(0, 0.3), rng.uniform(-np.pi, np.pi)])


def _world(name: str, request: pytest.FixtureRequest) -> World:
    if name == "bumpy":
        return bumpy_world()
    if name == "plane":
        return plane_world(0.4)
    return request.getfixturevalue(name)


def _same(a: np.ndarray, b: np.ndarray) -> None:
    assert a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(a, b)  # NaN == NaN here, inf == inf; everything else bit for bit


@pytest.mark.parametrize("cam", list(CAMERAS), ids=list(CAMERAS))
@pytest.mark.parametrize("name", ["mars_yard", "craters_world", "bumpy", "plane"])
def test_the_raster_gives_the_walks_ranges_and_clouds_bit_for_bit(name, cam, request):
    """On every pose the rasterised cast equals the plain walk: ranges with and without the sensor's window
    and range limit, and the point cloud the cast writes. Across the poses most rays are settled by the
    raster (it really runs) and some are walked past its box (that part is exercised too)."""
    world = _world(name, request)
    scene = heightfield_for(world)
    directions, pinhole = camera(*CAMERAS[cam])
    mount = np.array([0.2, 0.0, 0.25], np.float32)
    settled = walked = 0
    for origin, rotation in poses(world, np.random.default_rng(len(name) + len(cam)), 24):
        for max_range in (10.0, math.inf):
            _same(
                scene.cast_pose(directions, origin, rotation, max_range, pinhole=pinhole),
                scene.cast_pose(directions, origin, rotation, max_range),
            )
        ranges, cloud = scene.cast_frame(directions, origin, rotation, mount, 10.0, 0.2, pinhole)
        ref_ranges, ref_cloud = scene.cast_frame(directions, origin, rotation, mount, 10.0, 0.2)
        _same(ranges, ref_ranges)
        _same(cloud, ref_cloud)
        near, _ = scene._raster(directions, origin, rotation, pinhole)
        if near is not None:
            settled += int(np.isfinite(near).sum())
            walked += int((np.isinf(near) & np.isfinite(ref_ranges)).sum())
    total = 24 * len(directions)
    if cam != "looking_up":  # a camera looking at the sky sees little ground near it
        assert settled > 0.1 * total  # 13-83 % on these poses (a third of them 3 m up or at the map's edge)
    assert walked > 0  # and returns from beyond the box


def test_the_raster_is_skipped_where_it_cannot_prove_a_hit_nearest(mars_yard):
    """Off the map, or with terrain around the sensor within DELTA of its height, the raster stands aside
    (nothing is rasterised) and the walk alone gives the ranges."""
    scene = heightfield_for(mars_yard)
    directions, pinhole = camera(*CAMERAS["d435_64x48"])
    x, y = 3.0, -4.0
    ground = float(mars_yard.height(x, y))
    rotation = rpy_matrix([0.0, 0.0, 0.7])
    assert scene._raster(directions, np.array([x, y, ground + 0.5]), rotation, pinhole)[0] is not None
    for origin in (np.array([x, y, ground + 0.2 * DELTA]), np.array([mars_yard.bounds[1] + 1.0, y, ground + 1.0])):
        near, near_box = scene._raster(directions, origin, rotation, pinhole)
        assert near is None and near_box[0] > near_box[1]
        _same(
            scene.cast_pose(directions, origin, rotation, 10.0, pinhole=pinhole),
            scene.cast_pose(directions, origin, rotation, 10.0),
        )


def test_the_reach_is_capped_in_cells_on_a_fine_dem():
    """The box's cost grows as the square of its reach in cells: on 0.05 m cells it reaches REACH_CELLS cells
    (2 m), not 4 m, and the ranges stay the walk's."""
    fine = World("fine", Terrain(np.zeros((401, 401)), 20.0, 20.0), [])
    scene = heightfield_for(fine)
    directions, pinhole = camera(*CAMERAS["d435_64x48"])
    origin, rotation = np.array([0.0, 0.0, 0.35]), rpy_matrix([0.0, 0.0, 0.3])
    near, near_box = scene._raster(directions, origin, rotation, pinhole)
    assert near is not None and np.isfinite(near).sum() > 500
    span = max(near_box[1] - near_box[0], near_box[3] - near_box[2])
    assert REACH_CELLS <= span <= 2 * REACH_CELLS + 2  # uncapped, 4 m: ~120 cells
    _same(
        scene.cast_pose(directions, origin, rotation, 10.0, pinhole=pinhole),
        scene.cast_pose(directions, origin, rotation, 10.0),
    )


def test_depth_cameras_carry_their_pinhole_and_lidars_none(mars_yard):
    camera_sensor = make_sensor("depth_camera", mars_yard)
    pinhole = camera_sensor.caster.pinhole
    assert pinhole is not None and (pinhole.width, pinhole.height) == (64, 48)
    assert make_sensor("depth_camera_paper", mars_yard).caster.pinhole.width == 112
    assert make_sensor("lidar3d", mars_yard).caster.pinhole is None
    plain = RayCaster(mars_yard, camera_sensor.caster.directions, max_range=10.0)
    for origin, rotation in poses(mars_yard, np.random.default_rng(2), 8):
        _same(camera_sensor.caster.cast(origin, rotation, 0.2), plain.cast(origin, rotation, 0.2))


def test_a_pinhole_that_does_not_match_the_rays_is_refused(mars_yard):
    """A wrong model would make the raster test the wrong pixels and return wrong ranges silently."""
    directions, pinhole = camera(*CAMERAS["d435_64x48"])
    pinhole.check(directions)  # its own rays pass
    with pytest.raises(ValueError, match="1920 ray directions for a 64 x 48 image"):
        pinhole.check(lidar_pattern(16, -15.0, 15.0, 120).reshape(-1, 3))
    other, _ = camera(64, 48, 80.0, 58.0, 22.0)
    with pytest.raises(ValueError, match="not this camera's pixel rays"):
        RayCaster(mars_yard, other, pinhole=pinhole)
    flipped, _ = camera(64, 48, 87.0, 58.0, -22.0)  # mounted the other way
    with pytest.raises(ValueError, match="not this camera's pixel rays"):
        pinhole.check(flipped)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"width": 0}, "positive image size"),
        ({"tan_half_h": 0.0}, "positive finite half-angle tangents"),
        ({"tan_half_v": math.inf}, "positive finite half-angle tangents"),
        ({"mount_rotation": np.diag([1.0, 2.0, 1.0])}, "3 x 3 rotation matrix"),
        ({"mount_rotation": np.eye(2)}, "3 x 3 rotation matrix"),
    ],
)
def test_bad_pinhole_models_name_what_is_wrong(kwargs, message):
    good = {"width": 64, "height": 48, "tan_half_h": 0.9, "tan_half_v": 0.5, "mount_rotation": np.eye(3)}
    with pytest.raises(ValueError, match=message):
        Pinhole(**{**good, **kwargs})
