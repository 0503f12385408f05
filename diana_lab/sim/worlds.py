"""World builders, one per ``world=`` option. Each takes its typed config and returns a :class:`World`.

Procedural worlds draw every random number from ``numpy.random.default_rng(cfg.seed)``: the same seed gives
the same terrain, a new seed a new one.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.ndimage import distance_transform_edt, gaussian_filter
from scipy.spatial import ConvexHull

from diana_lab.config.sim import CratersConfig, DemConfig, FlatConfig, HillsConfig, MarsYardConfig, dem_size_missing
from diana_lab.core.validation import ConfigError
from diana_lab.sim.geotiff import read_geotiff
from diana_lab.sim.terrain import Terrain, grid_from_image
from diana_lab.sim.world import Obstacle, World

ASSETS = Path(__file__).resolve().parents[1] / "assets"
MARS_YARD_DEM = ASSETS / "marsyard2022" / "marsyard2022_terrain_hm.tif"
MARS_YARD_SIZE = 50.0  # metres, both axes (see assets/marsyard2022/README.md)

__all__ = ["Elevation", "craters", "dem", "flat", "hills", "load_elevation", "mars_yard", "read_elevation"]

log = logging.getLogger(__name__)


def _grid_shape(cfg: FlatConfig) -> tuple[int, int]:
    return int(round(cfg.size_y / cfg.resolution)) + 1, int(round(cfg.size_x / cfg.resolution)) + 1


def mars_yard(cfg: MarsYardConfig) -> World:
    """The ERC 2022 Mars Yard elevation model (MIT, Fictionlab), 50 m x 50 m, 257 x 257 samples."""
    return World(
        cfg.name,
        Terrain(_mars_yard_grid(), MARS_YARD_SIZE, MARS_YARD_SIZE),
        [],
        cfg.seed,
        cfg.obstacle_resolution,
    )


@lru_cache(maxsize=1)
def _mars_yard_grid() -> np.ndarray:
    return load_elevation(MARS_YARD_DEM, key="world (mars_yard asset)")


def flat(cfg: FlatConfig) -> World:
    return World(
        cfg.name,
        Terrain(np.zeros(_grid_shape(cfg)), cfg.size_x, cfg.size_y),
        [],
        cfg.seed,
        cfg.obstacle_resolution,
    )


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma_cells: float) -> np.ndarray:
    field = gaussian_filter(rng.standard_normal(shape), sigma_cells, mode="wrap")
    field -= field.mean()
    return field / (np.abs(field).max() + 1e-12)


def _limit_slope(heights: np.ndarray, spacing: float, max_slope_deg: float) -> np.ndarray:
    """Scale a height field so that its steepest slope (on the mesh) is at most ``max_slope_deg``."""
    gy, gx = np.gradient(heights, spacing)
    steepest = float(np.max(np.hypot(gx, gy)))
    # the triangulated surface is steeper than central differences; keep a margin for that
    limit = math.tan(math.radians(max_slope_deg)) * 0.8
    return heights * min(1.0, limit / steepest) if steepest > 0 else heights


def hills(cfg: HillsConfig) -> World:
    """Smooth rolling hills with gentle slopes (< ``max_slope_deg``): one of the paper's forgiving worlds."""
    rng = np.random.default_rng(cfg.seed)
    shape = _grid_shape(cfg)
    h = cfg.amplitude * _smooth_noise(rng, shape, cfg.feature_size / cfg.resolution / 2.0)
    h = _limit_slope(h, cfg.resolution, cfg.max_slope_deg)
    return World(cfg.name, Terrain(h - h.min(), cfg.size_x, cfg.size_y), [], cfg.seed, cfg.obstacle_resolution)


def _crater(x: np.ndarray, y: np.ndarray, cx: float, cy: float, radius: float, depth: float) -> np.ndarray:
    """A fresh simple crater: a parabolic bowl with a raised rim that fades into the plain."""
    r = np.hypot(x - cx, y - cy) / radius
    bowl = np.where(r < 1.0, depth * (r**2 - 1.0), 0.0)
    rim = 0.25 * depth * np.exp(-(((r - 1.0) / 0.35) ** 2))
    return bowl + rim


def _rock(rng: np.random.Generator, centre: np.ndarray, diameter: float, ground: float, name: str) -> Obstacle:
    """A convex, irregular rock half-buried in the ground."""
    directions = rng.standard_normal((24, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = np.array([0.5, 0.5 * rng.uniform(0.7, 1.0), 0.5 * rng.uniform(0.5, 0.8)]) * diameter
    points = directions * radii * rng.uniform(0.85, 1.0, size=(24, 1))
    yaw = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    points = points @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    hull = ConvexHull(points)
    vertices = points[hull.vertices]
    remap = {old: new for new, old in enumerate(hull.vertices)}
    triangles = np.vectorize(remap.get)(hull.simplices)
    # bury 30 % of the rock's height so it sits in the regolith instead of balancing on it
    offset = np.array([centre[0], centre[1], ground - vertices[:, 2].min() - 0.3 * np.ptp(vertices[:, 2])])
    return Obstacle(vertices + offset, triangles, name=name, convex=True)


def craters(cfg: CratersConfig) -> World:
    """Procedural Mars-like terrain: dunes, rimmed craters and scattered rocks (separate collision bodies)."""
    rng = np.random.default_rng(cfg.seed)
    ny, nx = _grid_shape(cfg)
    xs = -cfg.size_x / 2 + np.arange(nx) * cfg.resolution
    ys = -cfg.size_y / 2 + np.arange(ny) * cfg.resolution
    x, y = np.meshgrid(xs, ys)
    h = np.zeros_like(x)
    for _ in range(3):  # dunes: a few long-crested ripples in random directions
        theta, phase = rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi)
        wavelength = cfg.dune_wavelength * rng.uniform(0.7, 1.3)
        h += cfg.dune_amplitude / 3 * np.sin(2 * np.pi * (x * np.cos(theta) + y * np.sin(theta)) / wavelength + phase)
    h += 0.5 * cfg.dune_amplitude * _smooth_noise(rng, h.shape, 3.0 / cfg.resolution)
    lo, hi = cfg.crater_radius
    for _ in range(cfg.n_craters):
        radius = rng.uniform(lo, hi)
        cx = rng.uniform(-cfg.size_x / 2 + radius, cfg.size_x / 2 - radius)
        cy = rng.uniform(-cfg.size_y / 2 + radius, cfg.size_y / 2 - radius)
        h += _crater(x, y, cx, cy, radius, depth=0.2 * radius * rng.uniform(0.6, 1.0))
    h -= h.min()
    terrain = Terrain(h, cfg.size_x, cfg.size_y)
    n_rocks = int(rng.poisson(cfg.rock_density * cfg.size_x * cfg.size_y))
    margin = cfg.rock_size[1]
    rocks = []
    for i in range(n_rocks):
        px = rng.uniform(-cfg.size_x / 2 + margin, cfg.size_x / 2 - margin)
        py = rng.uniform(-cfg.size_y / 2 + margin, cfg.size_y / 2 - margin)
        diameter = rng.uniform(*cfg.rock_size)
        rocks.append(_rock(rng, np.array([px, py]), diameter, float(terrain.height(px, py)), f"rock_{i}"))
    return World(cfg.name, terrain, rocks, cfg.seed, cfg.obstacle_resolution)


# ----------------------------------------------------------------------------------------------- user DEMs


@dataclass(frozen=True)
class Elevation:
    """An elevation model read from a file: heights in grid order and, from a GeoTIFF's georeferencing, the
    spacing of its samples."""

    heights: np.ndarray  # grid order (see diana_lab.sim.terrain), before world.height_scale / height_offset
    spacing: tuple[float, float] | None  # (dx, dy) metres between samples; None: the file does not say


def load_elevation(path: str | Path, key: str = "world.path") -> np.ndarray:
    """The heights of :func:`read_elevation`, in grid order (cells without a height refused)."""
    return read_elevation(path, key).heights


def read_elevation(path: str | Path, key: str = "world.path", fill_nodata: bool = False) -> Elevation:
    """Read an elevation model in grid order (see :mod:`diana_lab.sim.terrain`).

    TIFF/GeoTIFF (rasterio) and ``.npy`` hold heights in metres; 8- and 16-bit PNGs hold 0..1 of the full scale
    (multiplied by ``world.height_scale`` afterwards). Image files store their first row at the north edge (a
    GeoTIFF whose transform says otherwise is turned so). Cells without a height (a GeoTIFF's nodata value or
    mask, NaN, infinity) are refused, naming how many and where, or with ``fill_nodata`` given the height of
    their nearest valid cell, with a warning.
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise ConfigError(f"{key}: file not found: '{path}' (expected a .tif/.tiff, .png or .npy elevation model)")
    suffix = path.suffix.lower()
    missing: np.ndarray | None = None
    nodata = spacing = None
    try:
        if suffix in (".tif", ".tiff"):
            raster = read_geotiff(path, key)
            data, missing, nodata, spacing = raster.image, raster.missing, raster.nodata, raster.spacing
        elif suffix == ".png":
            from PIL import Image

            with Image.open(path) as img:
                raw = np.asarray(img)
            full_scale = 65535.0 if raw.dtype == np.uint16 or raw.max() > 255 else 255.0
            data = raw.astype(np.float64) / full_scale
        elif suffix == ".npy":
            data = np.load(path, allow_pickle=False).astype(np.float64)
        else:
            raise ConfigError(f"{key}: unsupported format '{suffix}' of '{path}'; expected .tif, .tiff, .png or .npy")
    except ConfigError:
        raise
    except Exception as exc:
        raise ConfigError(f"{key}: could not read '{path}' as an elevation model ({exc})") from exc
    if data.ndim == 3 and data.shape[-1] in (3, 4):  # a grey image saved as RGB(A): its colours must agree
        rgb = data[..., :3]
        if not np.array_equal(rgb, np.broadcast_to(rgb[..., :1], rgb.shape), equal_nan=True):
            raise ConfigError(
                f"{key}: '{path}' is a colour image (its red, green and blue differ); expected a greyscale "
                "elevation model (one height per pixel)"
            )
        data = data[..., 0]
    if data.ndim != 2 or min(data.shape) < 2:
        raise ConfigError(f"{key}: '{path}' holds an array of shape {data.shape}; expected a 2-D grid of >= 2 x 2")
    missing = ~np.isfinite(data) if missing is None else missing | ~np.isfinite(data)
    if missing.any():
        data = _without_nodata(data, missing, path, key, nodata, spacing, fill_nodata)
    return Elevation(grid_from_image(data), None if spacing is None else (float(spacing[0]), float(spacing[1])))


def _without_nodata(
    data: np.ndarray,
    missing: np.ndarray,
    path: Path,
    key: str,
    nodata: float | None,
    spacing: tuple[float, float] | None,
    fill: bool,
) -> np.ndarray:
    """``data`` (image order) with its cells without a height refused, or filled from the nearest valid cell
    (nearest in metres where the spacing is known)."""
    n, total = int(np.count_nonzero(missing)), missing.size
    rows, cols = np.flatnonzero(missing.any(axis=1)), np.flatnonzero(missing.any(axis=0))
    what = f"the file's nodata value {nodata:g}, NaN or infinite" if nodata is not None else "NaN or infinite"
    where = (
        f"rows {rows[0]}..{rows[-1]}, columns {cols[0]}..{cols[-1]} of its {data.shape[0]} x {data.shape[1]} "
        "(row 0 = the north edge)"
    )
    if n == total:
        raise ConfigError(f"{key}: '{path}' has no cell with a height: all {n} are without one ({what})")
    if not fill:
        raise ConfigError(
            f"{key}: '{path}' has {n} of {total} cells without a height ({what}) in {where}; expected a height "
            "in every cell: crop the file to its valid part, or set world.fill_nodata=true to give each the "
            "height of its nearest valid cell"
        )
    sampling = None if spacing is None else (spacing[1], spacing[0])  # image order: rows (y), then columns (x)
    nearest = distance_transform_edt(missing, sampling=sampling, return_distances=False, return_indices=True)
    log.warning(
        "%s: filled %d of %d cells of '%s' without a height (%s; %s) with the height of their nearest valid "
        "cell (world.fill_nodata=true)",
        key,
        n,
        total,
        path,
        what,
        where,
    )
    return data[tuple(nearest)]


def _load_mesh(path: str, key: str) -> Obstacle:
    p = Path(path).expanduser()
    if not p.is_file():
        raise ConfigError(f"{key}: obstacle mesh not found: '{p}' (expected .obj, .stl or .ply in world coordinates)")
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(p))
    if len(mesh.triangles) < 4:
        raise ConfigError(f"{key}: '{p}' has no usable triangles (read {len(mesh.triangles)})")
    return Obstacle(np.asarray(mesh.vertices), np.asarray(mesh.triangles), name=p.stem, convex=False)


def _dem_extent(cfg: DemConfig, elevation: Elevation) -> tuple[float, float]:
    """``(size_x, size_y)``: the config's, or from the file's georeferencing; given both ways, they must agree
    within one sample spacing (a file's footprint, one spacing wider than its first-to-last extent, agrees)."""
    given = (("world.size_x", "x", cfg.size_x), ("world.size_y", "y", cfg.size_y))
    if elevation.spacing is None:
        missing = [
            dem_size_missing(k, axis, f"'{cfg.path}' has no georeferencing") for k, axis, v in given if v is None
        ]
        if missing:
            raise ConfigError("; ".join(missing))
        return float(cfg.size_x), float(cfg.size_y)  # type: ignore[arg-type]
    ny, nx = elevation.heights.shape
    sizes = []
    for (k, axis, value), n, step in zip(given, (nx, ny), elevation.spacing):
        extent = (n - 1) * step  # first sample to last: the grid's samples are its pixels' centres
        if value is not None and abs(value - extent) > step * (1.0 + 1e-9):
            raise ConfigError(
                f"{k}={value:g} disagrees with '{cfg.path}', whose georeferencing gives {extent:g} m along {axis} "
                f"({n} samples {step:g} m apart, first to last); leave {k} unset to take the file's, or give a "
                f"value within one sample ({step:g} m) of it"
            )
        sizes.append(extent if value is None else float(value))
    return sizes[0], sizes[1]


def dem(cfg: DemConfig) -> World:
    """The user's own terrain: an elevation file plus optional obstacle meshes in world coordinates.

    A GeoTIFF's spacing, square or not, is kept as it is (:class:`Terrain` has one spacing per axis); its
    geographic position is not: the terrain is centred on the world origin as every world is.
    """
    elevation = read_elevation(cfg.path, fill_nodata=cfg.fill_nodata)
    size_x, size_y = _dem_extent(cfg, elevation)
    heights = elevation.heights * cfg.height_scale + cfg.height_offset
    obstacles = [_load_mesh(path, f"world.obstacles[{i}]") for i, path in enumerate(cfg.obstacles)]
    return World(cfg.name, Terrain(heights, size_x, size_y), obstacles, cfg.seed, cfg.obstacle_resolution)
