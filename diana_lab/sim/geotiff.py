"""Reading a GeoTIFF/TIFF elevation model with rasterio: its heights, which cells have none, and its spacing.

A GeoTIFF says more than its pixels: where each pixel lies (the affine transform), in what units (the CRS) and
which value means "no measurement" (nodata). Reading only the pixels turns a ``-9999`` nodata cell into a pit
10 km deep and a survey in degrees into a terrain of a few metres, silently; this module reads all three, so
:func:`diana_lab.sim.worlds.read_elevation` can refuse or fill the cells without a height and take the extent
from the file.

rasterio is imported on first use: the onboard runtime and the procedural worlds never need it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from diana_lab.core.validation import ConfigError

__all__ = ["Raster", "read_geotiff"]


@dataclass(frozen=True)
class Raster:
    """A TIFF's bands in image order: row 0 the north edge, column 0 the west edge (flipped here if the
    transform says the file runs the other way)."""

    image: np.ndarray  # float64, (rows, cols) for one band, (rows, cols, bands) for several
    missing: np.ndarray  # bool (rows, cols): no height there (the nodata value, or masked by the file's mask)
    nodata: float | None  # the file's nodata value, for messages
    spacing: tuple[float, float] | None  # (along x, along y) metres between samples; None: not georeferenced


def read_geotiff(path: Path, key: str) -> Raster:
    """Read ``path`` with rasterio; refuse a rotated grid and a CRS not in metres, naming ``key`` and the file.

    Other read errors (not a TIFF, unreadable) propagate as rasterio raises them; the caller names the file.
    """
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        # a plain TIFF (no transform, no CRS) is fine here: the sizes then come from the config
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path) as src:
            if src.subdatasets:  # a multi-page TIFF: GDAL opens its first page only
                raise ConfigError(
                    f"{key}: '{path}' holds {len(src.subdatasets)} images (TIFF pages); expected one elevation "
                    "model (one band of heights)"
                )
            bands = src.read().astype(np.float64)  # (bands, rows, cols)
            missing = src.dataset_mask() == 0  # GDAL's mask: the nodata value, an internal mask or alpha band
            transform, crs, nodata = src.transform, src.crs, src.nodata
    if crs is not None:
        _check_crs(crs, path, key)
    spacing = None
    if not transform.is_identity:  # rasterio's identity: the file has no transform
        if transform.b != 0.0 or transform.d != 0.0:
            raise ConfigError(
                f"{key}: '{path}' is a rotated or sheared grid (transform {tuple(transform)[:6]}); expected "
                "rows along north-south and columns along east-west: warp it first (e.g. gdalwarp)"
            )
        # north-up (the usual) has a negative y pixel size: row 0 is the north edge, as the grid convention
        # wants; a positive one has row 0 at the south edge, a negative x size column 0 at the east edge
        if transform.e > 0:
            bands, missing = bands[:, ::-1, :], missing[::-1, :]
        if transform.a < 0:
            bands, missing = bands[:, :, ::-1], missing[:, ::-1]
        spacing = (abs(transform.a), abs(transform.e))
    image = bands[0] if len(bands) == 1 else np.moveaxis(bands, 0, -1)
    return Raster(np.ascontiguousarray(image), np.ascontiguousarray(missing), nodata, spacing)


def _check_crs(crs: object, path: Path, key: str) -> None:
    """Heights and extents are metres: a geographic CRS (degrees) or a projected one in feet is refused."""
    name = crs.to_string()  # type: ignore[attr-defined]  # "EPSG:4326", or its WKT where it has no code
    name = name if len(name) <= 100 else name[:100] + "..."
    if crs.is_geographic:  # type: ignore[attr-defined]
        raise ConfigError(
            f"{key}: '{path}' is in the geographic CRS {name} (degrees); expected a projected CRS in metres "
            "(heights and extents are metres): reproject it first, e.g. gdalwarp -t_srs EPSG:<its UTM zone>"
        )
    try:
        unit, factor = crs.linear_units_factor  # type: ignore[attr-defined]
    except Exception:  # no linear unit to read (e.g. a local CRS): taken as metres
        return
    if not np.isclose(factor, 1.0):
        raise ConfigError(
            f"{key}: '{path}' is in the CRS {name}, whose unit is the {unit} ({factor:g} m); expected metres: "
            "reproject it first (e.g. gdalwarp -t_srs with a CRS in metres)"
        )
