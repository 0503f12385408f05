"""Config schemas of the ``sensor`` group: ray-cast depth camera and 3-D lidar, their noise and encoding.

Lengths in metres, angles in degrees (keys ending in ``_deg``). The mount is given in the rover frame
(x forward, y left, z up, origin at the rover base link); ``mount_pitch_deg`` > 0 tilts the sensor down.
The classes named by ``_target_`` live in :mod:`diana_lab.sensing`; this module only names them, so that
composing a config never imports open3d.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from omegaconf import MISSING

from diana_lab.config.store import register
from diana_lab.core.validation import (
    ConfigError,
    boolean,
    in_range,
    length,
    non_negative,
    non_negative_int,
    one_of,
    ordered,
    positive,
    positive_int,
)

ENCODINGS = ("depth_image", "elevation_map", "points")
BACKENDS = ("heightfield", "open3d")  # ray casters: diana_lab/sensing/heightfield_cast.py, open3d RaycastingScene
NOISE_PRESETS = ("none", "realistic", "harsh")  # their numbers live in diana_lab/sensing/noise.py
POINT_METHODS = ("voxel", "fps")
MAX_RAYS = 1 << 20  # a frame of more rays than this is a typo, not a sensor


@dataclass
class ElevationMapConfig:
    """The ``elevation_map`` encoding: the cloud binned into a rover-centred, heading-aligned 2.5-D grid.

    Rows run along the rover heading (row 0 is ``extent_forward`` ahead), columns across it (column 0 is
    ``extent_side`` to the left). Each cell holds the highest point relative to the rover base, clipped to
    ``+-height_clip``; a second channel marks cells that received any point.

    ``memory: true`` fuses every frame of the episode into a world-frame map (``memory_radius`` around the
    episode's first pose, :class:`diana_lab.core.height_memory.HeightMemory`) and shows its window instead of the
    current frame alone: cells seen earlier stay known after they leave the field of view.

    ``hazard_radius > 0`` adds a third channel: 1 in the cells within that distance of a spot where one of the
    rover's drives was stopped this episode (the tilt guard's halt, a slope it could not climb;
    :class:`diana_lab.core.hazard_memory.HazardMemory`), so the policy knows where it has already failed.
    """

    cell_size: float = 0.25
    extent_forward: float = 8.0
    extent_back: float = 2.0
    extent_side: float = 5.0
    height_clip: float = 1.0
    voxel_size: float = 0.1  # open3d voxel down-sampling before binning; 0 turns it off
    outlier_removal: bool = False  # open3d statistical outlier removal (~3 ms a frame: off by default)
    nb_neighbors: int = 12
    std_ratio: float = 2.0
    memory: bool = False  # fuse the episode's frames into a world-frame map (see the class docstring)
    memory_radius: float = 64.0  # half-width of that map around the episode's first pose (m)
    hazard_radius: float = 0.0  # the stopped-drive channel's reach round each spot (m); 0: no such channel

    def __post_init__(self) -> None:
        key = "sensor.elevation_map"
        positive(f"{key}.cell_size", self.cell_size)
        positive(f"{key}.extent_forward", self.extent_forward)
        non_negative(f"{key}.extent_back", self.extent_back)
        positive(f"{key}.extent_side", self.extent_side)
        positive(f"{key}.height_clip", self.height_clip)
        non_negative(f"{key}.voxel_size", self.voxel_size)
        positive_int(f"{key}.nb_neighbors", self.nb_neighbors)
        positive(f"{key}.std_ratio", self.std_ratio)
        positive(f"{key}.memory_radius", self.memory_radius)
        non_negative(f"{key}.hazard_radius", self.hazard_radius)
        boolean(f"{key}.memory", self.memory)
        rows, cols = self.shape
        if rows * cols > 512 * 512:
            raise ConfigError(
                f"{key}.cell_size: {self.cell_size} gives a {rows} x {cols} grid; expected at most 512 x 512 cells"
            )

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the grid (at least one cell each way)."""
        rows = max(1, round((self.extent_forward + self.extent_back) / self.cell_size))
        cols = max(1, round(2.0 * self.extent_side / self.cell_size))
        return rows, cols

    @property
    def channels(self) -> int:
        """Height and known, plus the stopped-drive channel with ``hazard_radius > 0``."""
        return 3 if self.hazard_radius > 0 else 2


@dataclass
class PointsConfig:
    """The ``points`` encoding: a fixed-size set of ``n_points`` cloud points plus a validity mask."""

    n_points: int = 512
    method: str = "voxel"  # 'voxel' (voxel grid, then an even subsample) or 'fps' (farthest-point sampling)
    voxel_size: float = 0.1  # grid of the 'voxel' method (and a pre-filter for 'fps'); 0 turns it off

    def __post_init__(self) -> None:
        positive_int("sensor.points.n_points", self.n_points)
        one_of("sensor.points.method", self.method, POINT_METHODS)
        non_negative("sensor.points.voxel_size", self.voxel_size)


@dataclass
class SensorConfig:
    """Keys common to every ray-cast sensor.

    ``backend`` picks the ray caster; both hit the same triangles, and their ranges differ by open3d's float32
    rounding (tests: within 1e-4 m, tests/sensing/test_heightfield_cast.py):

    * ``heightfield`` (default): an exact numba ray marcher over the terrain grid plus the obstacle meshes
      (:mod:`diana_lab.sensing.heightfield_cast`), always one thread (``nthreads`` is ignored). Its first
      use in a fresh install compiles it (a few seconds, then cached in ``__pycache__``).
    * ``open3d``: open3d's ``RaycastingScene`` (Embree) over ``World.scene_mesh``, the reference; it runs on
      ``nthreads`` threads.
    """

    _target_: str = MISSING
    name: str = MISSING
    mount_xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.3])
    mount_pitch_deg: float = 0.0
    min_range: float = 0.1
    max_range: float = 10.0
    noise: str = "none"  # preset: none | realistic | harsh
    noise_level: float = 1.0  # scales every amplitude and probability of the preset
    encoding: str = "depth_image"  # depth_image | elevation_map | points
    backend: str = "heightfield"  # heightfield | open3d: the ray caster (see above)
    nthreads: int = 1  # open3d's ray-casting threads; 0 lets open3d use every core (heightfield: always 1)
    elevation_map: ElevationMapConfig = field(default_factory=ElevationMapConfig)
    points: PointsConfig = field(default_factory=PointsConfig)

    def __post_init__(self) -> None:
        length("sensor.mount_xyz", self.mount_xyz, 3)
        for i, v in enumerate(self.mount_xyz):
            in_range(f"sensor.mount_xyz[{i}]", v, -5.0, 5.0)
        in_range("sensor.mount_pitch_deg", self.mount_pitch_deg, -90.0, 90.0)
        non_negative("sensor.min_range", self.min_range)
        positive("sensor.max_range", self.max_range)
        ordered("sensor.min_range", self.min_range, "sensor.max_range", self.max_range)
        one_of("sensor.noise", self.noise, NOISE_PRESETS)
        non_negative("sensor.noise_level", self.noise_level)
        one_of("sensor.encoding", self.encoding, ENCODINGS)
        if self.elevation_map.hazard_radius > 0 and self.encoding != "elevation_map":
            raise ConfigError(
                f"sensor.elevation_map.hazard_radius={self.elevation_map.hazard_radius:g}: a channel of the "
                f"elevation_map encoding, but sensor.encoding={self.encoding}; set sensor.encoding=elevation_map "
                "or hazard_radius=0"
            )
        one_of("sensor.backend", self.backend, BACKENDS)
        non_negative_int("sensor.nthreads", self.nthreads)


@dataclass
class DepthCameraConfig(SensorConfig):
    """A pinhole depth camera (defaults: an Intel RealSense D435 at a low, RL-friendly resolution).

    Mounted 0.2 m ahead of and 0.25 m above the base origin of a Jackal-size rover (about 0.35 m above
    the ground) and pitched 22 deg down, its rows see flat ground from 0.5 m to 8.9 m ahead (the band the
    waypoints fall in fills most of the picture); the top 8 of 48 rows look above the horizon.
    """

    _target_: str = "diana_lab.sensing.camera.DepthCamera"
    name: str = "depth_camera"
    mount_xyz: list[float] = field(default_factory=lambda: [0.2, 0.0, 0.25])
    mount_pitch_deg: float = 22.0
    min_range: float = 0.2
    max_range: float = 10.0
    width: int = 64
    height: int = 48
    hfov_deg: float = 87.0
    vfov_deg: float = 58.0

    def __post_init__(self) -> None:
        super().__post_init__()
        positive_int("sensor.width", self.width)
        positive_int("sensor.height", self.height)
        in_range("sensor.hfov_deg", self.hfov_deg, 0.0, 180.0, inclusive=False)
        in_range("sensor.vfov_deg", self.vfov_deg, 0.0, 180.0, inclusive=False)
        if self.width * self.height > MAX_RAYS:
            raise ConfigError(
                f"sensor.width x sensor.height: expected at most {MAX_RAYS} pixels, got {self.width} x {self.height}"
            )


@dataclass
class Lidar3dConfig(SensorConfig):
    """A spinning multi-beam lidar (defaults: a Velodyne VLP-16's beams at 2 deg azimuth steps, 20 m)."""

    _target_: str = "diana_lab.sensing.lidar.Lidar3d"
    name: str = "lidar3d"
    mount_xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.3])
    mount_pitch_deg: float = 0.0
    min_range: float = 0.3
    max_range: float = 20.0
    beams: int = 16  # vertical channels
    vfov_min_deg: float = -15.0
    vfov_max_deg: float = 15.0
    horizontal_resolution_deg: float = 2.0  # azimuth step over the full 360 deg

    def __post_init__(self) -> None:
        super().__post_init__()
        positive_int("sensor.beams", self.beams)
        in_range("sensor.vfov_min_deg", self.vfov_min_deg, -90.0, 90.0)
        in_range("sensor.vfov_max_deg", self.vfov_max_deg, -90.0, 90.0)
        if self.beams > 1:
            ordered("sensor.vfov_min_deg", self.vfov_min_deg, "sensor.vfov_max_deg", self.vfov_max_deg)
        positive("sensor.horizontal_resolution_deg", self.horizontal_resolution_deg)
        in_range("sensor.horizontal_resolution_deg", self.horizontal_resolution_deg, 0.0, 360.0)
        if self.beams * self.columns > MAX_RAYS:
            raise ConfigError(
                f"sensor.horizontal_resolution_deg: {self.horizontal_resolution_deg} gives "
                f"{self.beams * self.columns} rays; expected at most {MAX_RAYS}"
            )

    @property
    def columns(self) -> int:
        """Azimuth samples per revolution (the resolution is rounded so that they tile 360 deg exactly)."""
        return max(1, round(360.0 / self.horizontal_resolution_deg))


# the paper's 112 x 112 preset and the main command's lidar use their sensor's schema under their own option name
register(
    "sensor",
    {
        "depth_camera": DepthCameraConfig,
        "depth_camera_paper": DepthCameraConfig,
        "lidar3d": Lidar3dConfig,
        "lidar_map": Lidar3dConfig,
    },
)
