"""The heightfield ray caster (``sensor.backend=heightfield``) against open3d, the reference, and geometry."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from omegaconf import OmegaConf

from diana_lab.config import ConfigError, compose, to_object
from diana_lab.core.rotations import pitch_matrix, rpy_matrix
from diana_lab.sensing.camera import pinhole_pattern
from diana_lab.sensing.heightfield_cast import heightfield_for, pose_rays
from diana_lab.sensing.lidar import lidar_pattern
from diana_lab.sensing.raycast import RayCaster
from tests.sensing.conftest import box, make_sensor, plane_world

TOL = 1e-4  # m: open3d casts in float32 (Embree); ours are float64, so this is open3d's rounding

CAMERA = pinhole_pattern(64, 48, 87.0, 58.0).reshape(-1, 3) @ pitch_matrix(math.radians(22.0)).T
LIDAR = lidar_pattern(16, -15.0, 15.0, 120).reshape(-1, 3)


def _poses(world, n, rng, lo=0.05, hi=2.0):
    """Sensor positions above the terrain (a few off the map or high above it) and tilted orientations."""
    x0, x1, y0, y1 = world.bounds
    for k in range(n):
        if k % 10 == 9:
            p = np.array([rng.uniform(1.5 * x0, 1.5 * x1), rng.uniform(1.5 * y0, 1.5 * y1), rng.uniform(-1.0, 20.0)])
        else:
            xy = rng.uniform([x0 + 1, y0 + 1], [x1 - 1, y1 - 1])
            p = np.array([*xy, float(world.height(*xy)) + rng.uniform(lo, hi)])
        yield p, rpy_matrix([rng.normal(0, 0.2), rng.normal(0, 0.2), rng.uniform(-np.pi, np.pi)])


def _compare(world, directions, poses, max_range=math.inf):
    """Cast the same rays with both backends: (hit/no-hit mismatches, max |difference| of common hits, hits)."""
    ref = RayCaster(world, directions, backend="open3d")
    ours = RayCaster(world, directions, backend="heightfield", max_range=max_range)
    mismatches, worst, hits = 0, 0.0, 0
    for origin, rotation in poses:
        a = ref.cast(origin, rotation)
        b = ours.cast(origin, rotation)
        np.testing.assert_array_equal(ref._rays, ours.rays(origin, rotation))  # the very same float32 rays
        if math.isfinite(max_range):
            a = np.where(a <= max_range, a, np.inf)
        both = np.isfinite(a) & np.isfinite(b)
        mismatches += int(np.count_nonzero(np.isfinite(a) != np.isfinite(b)))
        worst = max(worst, float(np.max(np.abs(a[both] - b[both]), initial=0.0)))
        hits += int(both.sum())
        assert b.dtype == np.float32 and b.shape == (len(directions),)
    return mismatches, worst, hits


@pytest.mark.parametrize("directions", [CAMERA, LIDAR], ids=["camera", "lidar"])
def test_agrees_with_open3d_on_the_mars_yard(mars_yard, directions):
    mismatches, worst, hits = _compare(mars_yard, directions, _poses(mars_yard, 30, np.random.default_rng(3)))
    assert hits > 10_000
    assert mismatches == 0
    assert worst < TOL


def test_agrees_with_open3d_among_rocks(craters_world):
    assert len(craters_world.obstacles) > 10
    rng = np.random.default_rng(4)
    # stand next to rocks, so that many rays hit them
    rocks = [ob.centre for ob in craters_world.obstacles[:20]]
    poses = []
    for c in rocks:
        xy = c[:2] + rng.normal(0.0, 1.5, 2)
        p = np.array([*xy, float(craters_world.height(*xy)) + rng.uniform(0.1, 1.0)])
        heading = math.atan2(c[1] - xy[1], c[0] - xy[0])
        poses.append((p, rpy_matrix([0.0, rng.normal(0, 0.1), heading])))
    for directions in (CAMERA, LIDAR):
        mismatches, worst, hits = _compare(craters_world, directions, poses)
        assert hits > 5_000 and mismatches == 0 and worst < TOL
    # the rocks are really in view: open3d against the terrain alone gives other ranges
    ours = RayCaster(craters_world, CAMERA)
    bare = type(craters_world)("bare", craters_world.terrain, [])
    alone = RayCaster(bare, CAMERA)
    changed = sum(int(np.count_nonzero(ours.cast(p, r) != alone.cast(p, r))) for p, r in poses)
    assert changed > 1_000


def test_agrees_with_open3d_with_boxes_off_the_map_and_from_below():
    boxes = [
        box((3, -1, 0), (4, 1, 1.5)),
        box((-5, 2, -1), (-2, 6, 0.8)),
        box((14, 14, 0), (22, 16, 2)),
    ]  # last: sticks out
    world = plane_world(0.3, size=30.0, obstacles=boxes)
    rng = np.random.default_rng(5)
    poses = list(_poses(world, 20, rng))
    poses += [(np.array([0.5, 0.5, -0.5]), rpy_matrix([0.0, -0.5, 0.3]))]  # under the ground, looking up
    for directions in (CAMERA, LIDAR):
        mismatches, worst, hits = _compare(world, directions, poses)
        assert hits > 2_000 and mismatches == 0 and worst < TOL


def test_rays_through_vertices_edges_and_diagonals_agree(mars_yard):
    terrain = mars_yard.terrain
    ny, nx = terrain.shape
    grid = terrain.mesh[0].reshape(ny, nx, 3)
    xs, ys = np.meshgrid(grid[0, 1 : nx - 1 : 9, 0], grid[1 : ny - 1 : 9, 0, 1])
    points = [
        np.stack([xs + fx * terrain.dx, ys + fy * terrain.dy], -1).reshape(-1, 2)
        for fx, fy in [(0, 0), (0.5, 0), (0, 0.5), (0.5, 0.5), (0.3, 0.7)]
    ]  # vertex, edges, on the diagonal, inside
    pts = np.concatenate(points)
    rays = np.zeros((len(pts), 6), np.float32)
    rays[:, :2], rays[:, 2], rays[:, 5] = pts, terrain.max_height + 1.0, -1.0
    import open3d as o3d

    from diana_lab.sensing.raycast import scene_for

    a = scene_for(mars_yard).cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    b = heightfield_for(mars_yard).cast(rays)
    assert np.isfinite(a).all() and np.isfinite(b).all()
    np.testing.assert_allclose(b, a, atol=TOL, rtol=0)
    np.testing.assert_allclose(b, terrain.max_height + 1.0 - terrain.height(pts[:, 0], pts[:, 1]), atol=1e-5)


@pytest.mark.parametrize("rpy", [(0.0, 0.0, 0.0), (0.1, -0.15, 2.0)])
def test_flat_plane_depth_is_analytic(rpy):
    plane_z = 1.25
    world = plane_world(plane_z)
    rotation = rpy_matrix(rpy)
    origin = np.array([1.0, -2.0, plane_z + 0.35])
    caster = RayCaster(world, CAMERA, max_range=math.inf)
    t = caster.cast(origin, rotation)
    rays = caster.rays(origin, rotation)  # the rays cast (whichever way the caster transforms them)
    d = rays[:, 3:].astype(np.float64)
    o = rays[0, :3].astype(np.float64)
    with np.errstate(divide="ignore"):
        expected = np.where(d[:, 2] < 0, (plane_z - o[2]) / d[:, 2], np.inf)
    on_map = np.isfinite(expected) & (expected < 25.0)  # the 60 m plane: hits closer than this are on it
    assert on_map.sum() > 2_000 and (~np.isfinite(expected)).sum() > 100
    np.testing.assert_allclose(t[on_map], expected[on_map], rtol=1e-6)
    assert np.isinf(t[~np.isfinite(expected)]).all()  # rays at or above the horizon


def test_rays_beyond_max_range_up_or_off_the_map_return_inf():
    world = plane_world(0.0, size=20.0)  # the map spans -10 .. 10 m
    scene = heightfield_for(world)

    def ray(origin, direction):
        d = np.asarray(direction, dtype=np.float64)
        return np.array([[*origin, *(d / np.linalg.norm(d))]], dtype=np.float32)

    down_far = ray((0.0, 0.0, 1.0), (1.0, 0.0, -0.12))  # hits the plane at ~8.4 m
    t = float(scene.cast(down_far)[0])
    assert t == pytest.approx(math.hypot(1.0, 0.12) / 0.12, rel=1e-6)
    assert np.isinf(scene.cast(down_far, 5.0)[0])  # beyond max range
    assert float(scene.cast(down_far, 8.5)[0]) == pytest.approx(t)
    assert np.isinf(scene.cast(ray((0.0, 0.0, 1.0), (0.0, 0.0, 1.0)))[0])  # straight up
    assert np.isinf(scene.cast(ray((0.0, 0.0, 1.0), (1.0, 0.3, 0.2)))[0])  # up and away
    assert np.isinf(scene.cast(ray((0.0, 0.0, 1.0), (1.0, 0.0, -0.05)))[0])  # would hit at 20 m: off the map
    assert np.isinf(scene.cast(ray((15.0, 0.0, 1.0), (1.0, 0.0, -0.5)))[0])  # starts off the map, points away
    assert float(scene.cast(ray((15.0, 0.0, 3.0), (-1.0, 0.0, -0.5)))[0]) == pytest.approx(3.0 * math.hypot(2, 1))


def test_sensor_frames_match_open3d_with_and_without_noise(mars_yard):
    rng = np.random.default_rng(8)
    poses = [(p, np.array([0.05, -0.03, rng.uniform(-3, 3)])) for p, _ in _poses(mars_yard, 6, rng, 0.1, 0.1)]
    for noise in ("none", "realistic"):
        ours = make_sensor("depth_camera", mars_yard, noise=noise)
        ref = make_sensor("depth_camera", mars_yard, noise=noise, backend="open3d")
        # without noise the caster stops rays at max_range; the noise model needs every hit (and draws per hit)
        assert ours.caster.max_range == (10.0 if noise == "none" else math.inf)
        ours.reset(np.random.default_rng(1))
        ref.reset(np.random.default_rng(1))
        for p, rpy in poses[:5]:
            a, b = ref.capture(p, rpy).ranges, ours.capture(p, rpy).ranges
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))  # same returns, same random draws
            # quantisation (5 mm) may round a 1e-5 m difference to the next step
            np.testing.assert_allclose(b[~np.isnan(b)], a[~np.isnan(a)], atol=TOL if noise == "none" else 6e-3)


def test_bad_backend_names_the_key_and_the_choices():
    node = OmegaConf.merge(compose(["sensor=depth_camera"]).sensor, OmegaConf.from_dotlist(["backend=embree"]))
    with pytest.raises(ConfigError, match=r"sensor\.backend: expected one of 'heightfield', 'open3d', got 'embree'"):
        to_object("sensor", node)
    with pytest.raises(ConfigError, match=r"sensor\.backend"):
        RayCaster(plane_world(0.0), CAMERA, backend="embree")
    assert to_object("sensor", "depth_camera").backend == "heightfield"


def test_pickled_caster_drops_its_scene_and_still_casts():
    world = plane_world(0.0, obstacles=[box((3.0, -1.0, 0.0), (4.0, 1.0, 1.0))])
    caster = RayCaster(world, CAMERA, max_range=10.0)
    pose = (np.array([0.0, 0.0, 0.35]), np.eye(3))
    first = caster.cast(*pose)
    clone = pickle.loads(pickle.dumps(caster))
    assert clone._scene is None and clone.backend == "heightfield" and clone.max_range == 10.0
    np.testing.assert_array_equal(clone.cast(*pose), first)
    assert np.isfinite(first).sum() > 1_000


def _pose_cases(world, rng, n=12):
    for origin, rotation in _poses(world, n, rng):
        yield np.asarray(origin, dtype=np.float64), rotation
    yield np.array([world.bounds[1] + 3.0, 0.5, 2.0]), rpy_matrix([0.0, 0.3, math.pi])  # off the map, looking in


@pytest.mark.parametrize("name", ["mars_yard", "craters_world"])
def test_pose_cast_casts_exactly_the_pose_rays(name, request):
    """``cast_pose`` transforms the rays in the kernel: the very rays ``pose_rays`` writes (float32 origin, the
    float32 rotation times the directions in float64, rounded once), so both give the same ranges bit for bit.
    Against numpy's float32 matmul (what ``RayCaster.rays`` computed before) they differ by rounding only."""
    world = request.getfixturevalue(name)
    scene = heightfield_for(world)
    assert (scene.n_obstacles > 10) == (name == "craters_world")
    for pattern in (CAMERA, LIDAR):
        directions = np.ascontiguousarray(pattern, dtype=np.float32)
        buf = np.empty((len(directions), 6), np.float32)
        for origin, rotation in _pose_cases(world, np.random.default_rng(11)):
            rays = pose_rays(directions, origin, rotation, buf)
            np.testing.assert_array_equal(rays[:, :3], np.broadcast_to(origin.astype(np.float32), (len(rays), 3)))
            r32 = rotation.astype(np.float32).astype(np.float64)
            exact = directions.astype(np.float64) @ r32.T
            assert np.max(np.abs(rays[:, 3:] - exact)) <= 2.0**-25  # one rounding to float32: half an ulp (< 1)
            numpy32 = directions @ rotation.T.astype(np.float32)
            assert np.max(np.abs(rays[:, 3:] - numpy32)) <= 2.0**-23  # the numpy transform: rounding apart
            for max_range in (10.0, math.inf):
                np.testing.assert_array_equal(
                    scene.cast_pose(directions, origin, rotation, max_range), scene.cast(rays, max_range)
                )


def test_pose_cast_agrees_with_open3d(mars_yard, craters_world):
    """open3d casting ``pose_rays``'s rays: the same hits as ``cast_pose``, to open3d's rounding."""
    import open3d as o3d

    from diana_lab.sensing.raycast import scene_for

    for world in (mars_yard, craters_world):
        scene, ref = heightfield_for(world), scene_for(world)
        directions = np.ascontiguousarray(CAMERA, dtype=np.float32)
        buf = np.empty((len(directions), 6), np.float32)
        mismatches, worst, hits = 0, 0.0, 0
        for origin, rotation in _pose_cases(world, np.random.default_rng(12), 20):
            a = ref.cast_rays(o3d.core.Tensor(pose_rays(directions, origin, rotation, buf)))["t_hit"].numpy()
            a = np.where(a <= 20.0, a, np.inf)  # Embree's float32 error grows with the range (1e-4 m at 45 m)
            b = scene.cast_pose(directions, origin, rotation, 20.0)
            both = np.isfinite(a) & np.isfinite(b)
            mismatches += int(np.count_nonzero(np.isfinite(a) != np.isfinite(b)))
            worst = max(worst, float(np.max(np.abs(a[both] - b[both]), initial=0.0)))
            hits += int(both.sum())
        assert hits > 10_000 and mismatches == 0 and worst < TOL


def test_pose_cast_with_min_range_gives_the_sensor_ranges(mars_yard):
    """With ``min_range`` the kernel NaNs no hit and ranges outside ``[min_range, max_range]`` itself, exactly
    as the sensor masks them (float32 comparisons with the Python floats)."""
    scene = heightfield_for(mars_yard)
    directions = np.ascontiguousarray(CAMERA, dtype=np.float32)
    rng = np.random.default_rng(13)
    near = 0
    for origin, rotation in _pose_cases(mars_yard, rng):
        for lo, hi in ((0.2, 10.0), (0.45, 3.0)):
            t = scene.cast_pose(directions, origin, rotation, hi)
            expected = t.copy()
            np.putmask(expected, (t < lo) | (t > hi), np.float32(np.nan))
            got = scene.cast_pose(directions, origin, rotation, hi, min_range=lo)
            np.testing.assert_array_equal(got, expected)
            assert got.dtype == np.float32
            near += int(np.count_nonzero(t < lo))
    assert near > 100  # some hits closer than min_range really were masked
