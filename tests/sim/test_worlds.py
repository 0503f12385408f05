import math

import numpy as np
import pytest
import tifffile
from PIL import Image

from diana_lab.config import ConfigError, build, to_object
from tests.conftest import world_from_config


def test_every_world_exposes_height_bounds_and_scene_mesh():
    for name in ("mars_yard", "flat", "hills", "craters"):
        world = world_from_config([f"world={name}"])
        vertices, triangles = world.scene_mesh
        assert vertices.dtype == np.float32 and triangles.dtype == np.int32
        assert triangles.max() < len(vertices)
        x0, x1, y0, y1 = world.bounds
        assert x1 > x0 and y1 > y0
        assert np.isfinite(world.height(np.array([x0, 0.0, x1]), np.array([y0, 0.0, y1]))).all()


def test_hills_are_gentle(hills_world):
    # the steepest triangle of the mesh, not just the central differences
    v, t = hills_world.terrain.mesh
    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    slope = np.degrees(np.arccos(np.abs(n[:, 2]) / np.linalg.norm(n, axis=1)))
    assert slope.max() < 10.0
    assert np.ptp(hills_world.terrain.heights) > 0.3  # and not flat either


def test_craters_are_seeded_and_have_rocks():
    a = world_from_config(["world=craters", "world.seed=1"])
    b = world_from_config(["world=craters", "world.seed=1"])
    c = world_from_config(["world=craters", "world.seed=2"])
    np.testing.assert_array_equal(a.terrain.heights, b.terrain.heights)
    assert len(a.obstacles) == len(b.obstacles) > 10
    np.testing.assert_array_equal(a.obstacles[0].vertices, b.obstacles[0].vertices)
    assert not np.array_equal(a.terrain.heights, c.terrain.heights)
    # rocks are separate bodies that stick out of the ground and show up in the obstacle raster
    assert a.obstacle_map.height.max() > 0.1
    rock = a.obstacles[0]
    top = rock.vertices[:, 2].max()
    assert top > a.height(*rock.centre[:2])


def test_rock_density_is_configurable():
    few = world_from_config(["world=craters", "world.rock_density=0.002"])
    many = world_from_config(["world=craters", "world.rock_density=0.04"])
    assert len(many.obstacles) > 5 * max(len(few.obstacles), 1)


@pytest.mark.parametrize("suffix", [".tif", ".npy", ".png", "_rgb.png"])
def test_dem_world_reads_user_files(tmp_path, suffix):
    grid = np.outer(np.linspace(0, 1, 20), np.ones(30))  # rises towards the image bottom = south
    path = tmp_path / f"site{suffix}"
    if suffix == ".tif":
        tifffile.imwrite(path, grid)
    elif suffix == ".npy":
        np.save(path, grid)
    elif suffix == ".png":
        Image.fromarray((grid * 65535).astype(np.uint16)).save(path)
    else:  # a grey height map saved with colour channels (8 bits: heights within 1/255 of the scale)
        Image.fromarray(np.repeat((grid * 255).round().astype(np.uint8)[..., None], 3, axis=2)).save(path)
    world = build(
        to_object(
            "world",
            {
                "name": "dem",
                "path": str(path),
                "size_x": 30.0,
                "size_y": 20.0,
                "height_scale": 2.0,
                "height_offset": 1.0,
            },
        )
    )
    assert world.terrain.shape == (20, 30)
    assert world.height(0.0, -10.0) == pytest.approx(3.0, abs=1e-3)  # south edge: image bottom row, 1 * 2 + 1
    assert world.height(0.0, 10.0) == pytest.approx(1.0, abs=1e-3)


def test_dem_world_with_obstacle_mesh(tmp_path):
    import open3d as o3d

    np.save(tmp_path / "g.npy", np.zeros((11, 11)))
    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    box.translate((2.0, 2.0, 0.0))
    o3d.io.write_triangle_mesh(str(tmp_path / "box.obj"), box)
    world = build(
        to_object(
            "world",
            {
                "name": "dem",
                "path": str(tmp_path / "g.npy"),
                "size_x": 10.0,
                "size_y": 10.0,
                "obstacles": [str(tmp_path / "box.obj")],
            },
        )
    )
    assert len(world.obstacles) == 1
    assert world.obstacle_map.lookup(np.array([2.5]), np.array([2.5]))[0] == pytest.approx(1.0, abs=1e-3)
    assert world.obstacle_map.lookup(np.array([-2.0]), np.array([-2.0]))[0] == 0.0


@pytest.mark.parametrize(
    ("setup", "key", "expected"),
    [
        ("missing", "world.path", "file not found"),
        ("nan", "world.path", "NaN"),
        ("garbage", "world.path", "could not read"),
        ("txt", "world.path", "unsupported format"),
        ("mesh", "world.obstacles[0]", "not found"),
        ("stack", "world.path", "shape (3, 4, 5)"),  # was read as its first of 5 layers, without a word
        ("colour", "world.path", "colour image"),
    ],
)
def test_dem_errors_name_the_key_and_file(tmp_path, setup, key, expected):
    path = tmp_path / "dem.npy"
    obstacles = []
    if setup == "nan":
        np.save(path, np.full((4, 4), math.nan))
    elif setup == "stack":
        np.save(path, np.zeros((3, 4, 5)))
    elif setup == "colour":
        path = tmp_path / "dem.png"
        rgb = np.zeros((4, 4, 3), dtype=np.uint8)
        rgb[..., 0] = 200  # red where a height map would be grey
        Image.fromarray(rgb).save(path)
    elif setup == "garbage":
        path = tmp_path / "dem.tif"
        path.write_bytes(b"not a tiff")
    elif setup == "txt":
        path = tmp_path / "dem.txt"
        path.write_text("1 2 3")
    elif setup == "mesh":
        np.save(path, np.zeros((4, 4)))
        obstacles = [str(tmp_path / "nope.obj")]
    with pytest.raises(ConfigError) as err:
        build(
            to_object(
                "world",
                {"name": "dem", "path": str(path), "size_x": 5.0, "size_y": 5.0, "obstacles": obstacles},
            )
        )
    assert key in str(err.value) and expected in str(err.value)
