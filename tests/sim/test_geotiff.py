"""``world=dem`` on GeoTIFFs: the extent from the transform, nodata refused or filled, metres only, orientation.

Every file is a small GeoTIFF written here with rasterio; the worlds are composed from the real ``conf/world/dem.yaml``.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np
import pytest
import rasterio
import tifffile
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import Affine

from diana_lab.config import ConfigError
from diana_lab.sim.terrain import grid_from_image
from diana_lab.sim.worlds import MARS_YARD_DEM, load_elevation
from tests.conftest import world_from_config

UTM = "EPSG:32633"  # WGS 84 / UTM zone 33N: metres


def from_origin(west: float, north: float, dx: float, dy: float) -> Affine:
    """A north-up transform (rasterio's ``from_origin``, without its deprecated ``*`` of two affines)."""
    return Affine(dx, 0.0, west, 0.0, -dy, north)


def plane(rows: int, cols: int) -> np.ndarray:
    """Image-ordered heights (row 0 = north) rising 0.1 m a column eastwards and 1 m a row southwards."""
    r, c = np.mgrid[0:rows, 0:cols]
    return 0.1 * c + 1.0 * r


def write_tif(path, image, transform=None, crs=UTM, nodata=None):
    profile = {"driver": "GTiff", "height": image.shape[0], "width": image.shape[1], "count": 1, "dtype": "float64"}
    if transform is not None:
        profile["transform"] = transform
    if crs is not None:
        profile["crs"] = crs
    if nodata is not None:
        profile["nodata"] = nodata
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile) as dst:
            dst.write(image.astype(np.float64), 1)
    return path


def dem_world(path, *overrides):
    return world_from_config(["world=dem", f"world.path={path}", *overrides])


def refusal(path, *overrides) -> str:
    with pytest.raises(ConfigError) as err:
        dem_world(path, *overrides)
    return str(err.value)


# ----------------------------------------------------------------------------------------------- extent


@pytest.mark.parametrize("layout", ["north_up", "south_up"])
def test_extent_and_orientation_come_from_the_transform(tmp_path, layout):
    image = plane(11, 21)  # 0.5 m pixels: 10 m x 5 m from the first sample to the last
    if layout == "north_up":  # the usual: negative y pixel size, row 0 at the north edge
        path = write_tif(tmp_path / "site.tif", image, from_origin(500_000.0, 5_800_000.0, 0.5, 0.5))
    else:  # the same terrain stored south edge first: positive y pixel size
        transform = Affine(0.5, 0.0, 500_000.0, 0.0, 0.5, 5_799_994.5)
        path = write_tif(tmp_path / "site.tif", image[::-1], transform)
    world = dem_world(path)
    assert world.terrain.shape == (11, 21)
    assert (world.terrain.size_x, world.terrain.size_y) == pytest.approx((10.0, 5.0))
    assert world.height(-5.0, 2.5) == pytest.approx(0.0)  # north-west corner: image row 0, column 0
    assert world.height(5.0, 2.5) == pytest.approx(2.0)  # north-east: column 20
    assert world.height(-5.0, -2.5) == pytest.approx(10.0)  # south-west: row 10


def test_given_sizes_within_one_cell_of_the_file_are_taken(tmp_path):
    path = write_tif(tmp_path / "site.tif", plane(11, 21), from_origin(0.0, 0.0, 0.5, 0.5))
    # the footprint (21 pixels x 0.5 m = 10.5 m) is one cell wider than first-to-last (10 m): both agree
    world = dem_world(path, "world.size_x=10.5", "world.size_y=5")
    assert (world.terrain.size_x, world.terrain.size_y) == (10.5, 5.0)


@pytest.mark.parametrize(
    ("override", "given", "file_extent"), [("world.size_x=12", "12", "10"), ("world.size_y=4.4", "4.4", "5")]
)
def test_given_sizes_that_disagree_with_the_file_are_refused_naming_both(tmp_path, override, given, file_extent):
    path = write_tif(tmp_path / "site.tif", plane(11, 21), from_origin(0.0, 0.0, 0.5, 0.5))
    message = refusal(path, override)
    key = override.split("=")[0]
    assert f"{key}={given} disagrees" in message and f"gives {file_extent} m" in message and str(path) in message


def test_non_square_pixels_keep_their_spacing(tmp_path):
    """0.5 m along x, 2 m along y: the terrain keeps one spacing per axis (no resampling)."""
    path = write_tif(tmp_path / "site.tif", plane(5, 9), from_origin(0.0, 0.0, 0.5, 2.0))
    terrain = dem_world(path).terrain
    assert terrain.shape == (5, 9)
    assert (terrain.size_x, terrain.size_y) == pytest.approx((4.0, 8.0))
    assert (terrain.dx, terrain.dy) == pytest.approx((0.5, 2.0))
    x = np.array([-2.0, 1.0, 1.25, 0.3, 2.0])
    y = np.array([4.0, 0.0, -1.0, 3.1, -4.0])
    column, row = (x + 2.0) / 0.5, (4.0 - y) / 2.0  # row 0 at the north edge, y = +4
    np.testing.assert_allclose(terrain.height(x, y), 0.1 * column + row, atol=1e-9)


def test_a_plain_tiff_needs_the_sizes(tmp_path):
    path = tmp_path / "plain.tif"
    tifffile.imwrite(path, plane(4, 6))  # no transform, no CRS
    world = dem_world(path, "world.size_x=10", "world.size_y=6")
    assert (world.terrain.size_x, world.terrain.size_y) == (10.0, 6.0)
    assert world.height(5.0, 3.0) == pytest.approx(0.5)  # north-east: row 0, column 5
    assert world.height(-5.0, -3.0) == pytest.approx(3.0)  # south-west: row 3, column 0
    message = refusal(path)
    assert "world.size_x: missing" in message and "world.size_y: missing" in message
    assert "has no georeferencing" in message and str(path) in message


# ----------------------------------------------------------------------------------------------- nodata


def holed(nodata: float | None = -9999.0) -> np.ndarray:
    image = plane(8, 10)
    image[2, 4] = image[2, 5] = image[3, 4] = -9999.0 if nodata is not None else np.nan
    image[6, 7] = np.nan  # NaN counts as no height whatever the nodata value
    return image


def test_nodata_cells_are_refused_with_their_count_and_place(tmp_path):
    path = write_tif(tmp_path / "site.tif", holed(), from_origin(0.0, 0.0, 1.0, 1.0), nodata=-9999.0)
    message = refusal(path)
    assert message.startswith("world.path: ") and str(path) in message
    assert "4 of 80 cells without a height" in message and "nodata value -9999" in message
    assert "rows 2..6, columns 4..7" in message and "world.fill_nodata=true" in message


def test_nan_cells_of_a_file_without_nodata_are_refused(tmp_path):
    path = write_tif(tmp_path / "site.tif", holed(nodata=None), from_origin(0.0, 0.0, 1.0, 1.0))
    message = refusal(path)
    assert "4 of 80 cells without a height (NaN or infinite)" in message


def test_fill_nodata_takes_the_nearest_valid_cell_and_says_so(tmp_path, caplog):
    """Pixels 0.5 m wide and 1 m tall: the nearest valid cell, in metres, is along the row (in pixels, the one
    above or below would tie with it)."""
    image = holed()
    path = write_tif(tmp_path / "site.tif", image, from_origin(0.0, 0.0, 0.5, 1.0), nodata=-9999.0)
    with caplog.at_level(logging.WARNING, logger="diana_lab.sim.worlds"):
        world = dem_world(path, "world.fill_nodata=true")
    assert "filled 4 of 80 cells" in caplog.text and str(path) in caplog.text
    filled = world.terrain.heights[::-1]  # back to image order
    expected = plane(8, 10)
    # the nearest valid cells 0.5 m away (two where both sides of a hole are valid); 1 m away is never taken
    nearest = {(2, 4): [(2, 3)], (2, 5): [(2, 6)], (3, 4): [(3, 3), (3, 5)], (6, 7): [(6, 6), (6, 8)]}
    for cell, sources in nearest.items():
        assert filled[cell] in [expected[s] for s in sources], (cell, filled[cell])
    valid = np.isfinite(image) & (image != -9999.0)
    np.testing.assert_array_equal(filled[valid], expected[valid])  # the others untouched


def test_a_file_of_nodata_only_is_refused_even_with_fill(tmp_path):
    path = write_tif(tmp_path / "site.tif", np.full((4, 4), -1.0), from_origin(0.0, 0.0, 1.0, 1.0), nodata=-1.0)
    assert "no cell with a height" in refusal(path, "world.fill_nodata=true")


def test_the_shipped_yard_still_reads_as_its_pixels():
    """The yard's TIFF is georeferenced with GDAL_NODATA=0 and has no zero cell: nothing refused or changed."""
    np.testing.assert_array_equal(load_elevation(MARS_YARD_DEM), grid_from_image(tifffile.imread(MARS_YARD_DEM)))


# ----------------------------------------------------------------------------------------------- units


def test_a_geographic_crs_is_refused_naming_it(tmp_path):
    path = write_tif(tmp_path / "site.tif", plane(4, 4), from_origin(13.4, 52.5, 1e-4, 1e-4), crs="EPSG:4326")
    message = refusal(path)
    assert message.startswith("world.path: ") and "geographic CRS EPSG:4326" in message and "metres" in message


def test_a_crs_in_feet_is_refused(tmp_path):
    path = write_tif(tmp_path / "site.tif", plane(4, 4), from_origin(6e6, 2e6, 1.0, 1.0), crs="EPSG:2227")
    message = refusal(path)
    assert "EPSG:2227" in message and "expected metres" in message


def test_a_multi_page_tiff_is_refused(tmp_path):
    path = tmp_path / "pages.tif"
    tifffile.imwrite(path, plane(4, 6))
    tifffile.imwrite(path, plane(4, 6) + 1.0, append=True)  # a second page GDAL would leave unread
    message = refusal(path, "world.size_x=5", "world.size_y=3")
    assert "holds 2 images (TIFF pages)" in message and str(path) in message


def test_a_rotated_grid_is_refused(tmp_path):
    path = write_tif(tmp_path / "site.tif", plane(4, 4), Affine(0.5, 0.1, 0.0, 0.1, -0.5, 0.0))
    assert "rotated or sheared" in refusal(path)
