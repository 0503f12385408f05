import numpy as np
import pytest
import tifffile

from diana_lab.sim.terrain import Terrain, grid_from_image
from diana_lab.sim.worlds import MARS_YARD_DEM


def test_mars_yard_orientation_is_pinned(mars_yard):
    """Image row 0 is the north (+y) edge, column 0 the west (-x) edge: the hill top lands where predicted."""
    image = tifffile.imread(MARS_YARD_DEM)
    row, col = np.unravel_index(np.argmax(image), image.shape)
    spacing = 50.0 / 256
    expected_x, expected_y = -25.0 + col * spacing, 25.0 - row * spacing
    assert mars_yard.height(expected_x, expected_y) == pytest.approx(image.max())
    assert mars_yard.terrain.bounds == (-25.0, 25.0, -25.0, 25.0)
    assert mars_yard.terrain.shape == (257, 257)
    # and the opposite corner mapping: image (0, 0) is the north-west corner
    assert mars_yard.height(-25.0, 25.0) == pytest.approx(image[0, 0])
    assert mars_yard.height(25.0, -25.0) == pytest.approx(image[-1, -1])


def test_mars_yard_heights_match_the_published_range(mars_yard):
    h = mars_yard.terrain.heights
    assert h.min() == pytest.approx(0.014, abs=1e-3)
    assert h.max() == pytest.approx(4.821, abs=1e-3)
    assert h.mean() == pytest.approx(1.20, abs=0.01)


def test_height_query_is_the_mesh_surface(mars_yard, rng):
    """Random points: height(x, y) lies on the triangle of the mesh that contains (x, y)."""
    import open3d as o3d

    vertices, triangles = mars_yard.terrain.mesh
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(vertices, triangles.astype(np.uint32))
    xy = rng.uniform(-24.9, 24.9, size=(500, 2))
    rays = np.column_stack([xy, np.full(500, 10.0), np.zeros(500), np.zeros(500), -np.ones(500)]).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    np.testing.assert_allclose(10.0 - hit, mars_yard.height(xy[:, 0], xy[:, 1]), atol=1e-4)


def test_height_is_bilinear_exact_on_a_plane():
    x = np.linspace(-5, 5, 11)
    grid = np.tile(0.3 * x, (11, 1)) + 0.1 * np.linspace(-5, 5, 11)[:, None]
    terrain = Terrain(grid, 10.0, 10.0)
    px, py = np.array([-4.3, 0.0, 2.77]), np.array([1.1, -3.3, 4.9])
    np.testing.assert_allclose(terrain.height(px, py), 0.3 * px + 0.1 * py, atol=1e-12)
    n = terrain.normal(0.2, 0.3)
    np.testing.assert_allclose(n, np.array([-0.3, -0.1, 1.0]) / np.linalg.norm([-0.3, -0.1, 1.0]), atol=1e-12)


def test_grid_from_image_flips_rows_only():
    image = np.arange(12.0).reshape(3, 4)
    np.testing.assert_array_equal(grid_from_image(image), image[::-1])


@pytest.mark.parametrize(
    ("grid", "size", "message"),
    [
        (np.full((3, 3), np.nan), (1.0, 1.0), "NaN"),
        (np.zeros(5), (1.0, 1.0), "2-D grid"),
        (np.zeros((3, 3)), (0.0, 1.0), "positive sizes"),
    ],
)
def test_bad_terrain_is_rejected(grid, size, message):
    with pytest.raises(ValueError, match=message):
        Terrain(grid, *size)
