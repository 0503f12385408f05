"""The ray-cast range sensor the env uses: a fixed ray pattern on a mount, noise, and an encoder.

Subclasses only say where their rays point (:meth:`RaySensor.pattern`); everything else (pose transform,
casting, range limits, noise, encoding, pickling) is shared. The env's calls:

    sensor = diana_lab.config.build(cfg.sensor, world)     # DepthCamera(cfg, world) / Lidar3d(cfg, world)
    sensor.observation_space                               # Box of the configured encoding
    sensor.reset(self.np_random)                           # per episode: generator and noise state
    obs = sensor.observe(state.position, state.rpy)        # capture + encode
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces

from diana_lab.config.sensing import SensorConfig
from diana_lab.core.rotations import pitch_matrix, rpy_matrix
from diana_lab.sensing.encoders import Encoder, make_encoder
from diana_lab.sensing.frame import SensorFrame
from diana_lab.sensing.noise import NoiseModel
from diana_lab.sensing.pinhole import Pinhole
from diana_lab.sensing.raycast import RayCaster
from diana_lab.sim.world import World

__all__ = ["RaySensor"]


class RaySensor:
    """Base class of the ray-cast sensors. ``cfg`` is the typed ``sensor`` config (any ``SensorConfig``)."""

    cfg: SensorConfig

    def __init__(self, cfg: SensorConfig, world: World) -> None:
        self.cfg = cfg
        self.world = world
        pattern = np.asarray(self.pattern(), dtype=np.float64)  # (H, W, 3) unit vectors, sensor frame
        self.image_shape: tuple[int, int] = (pattern.shape[0], pattern.shape[1])
        mount_rotation = pitch_matrix(math.radians(cfg.mount_pitch_deg))
        directions = pattern.reshape(-1, 3) @ mount_rotation.T  # rover frame
        self.mount = np.asarray(cfg.mount_xyz, dtype=np.float64)
        self.axis_cos = self.optical_axis_cos(pattern)
        self.noise = NoiseModel(cfg.noise, cfg.noise_level, self.image_shape, cfg.min_range)
        # the heightfield backend may stop rays at max_range, but only without noise: the noise model draws
        # one range error per hit (and can pull a hit beyond max_range back in), so a noisy sensor gets all
        # hits, as with open3d, and the same frames for the same seed with either backend
        cast_range = math.inf if self.noise.active else float(cfg.max_range)
        self.caster = RayCaster(
            world,
            directions,
            cfg.nthreads,
            backend=cfg.backend,
            max_range=cast_range,
            pinhole=self.pinhole(mount_rotation),
        )
        self.encoder: Encoder = make_encoder(cfg, self.image_shape, self.axis_cos)
        self.rng = np.random.default_rng(0)  # replaced by reset(); keeps capture() usable before it
        self._mount32 = self.mount.astype(np.float32)
        self.last_frame: SensorFrame | None = None  # the frame of the latest observe()

    # ------------------------------------------------------------------ what subclasses define
    def pattern(self) -> np.ndarray:
        """``(H, W, 3)`` unit ray directions in the sensor frame (x forward, y left, z up)."""
        raise NotImplementedError

    def pinhole(self, mount_rotation: np.ndarray) -> Pinhole | None:
        """The pinhole camera whose pixel rays :meth:`pattern` gives, mounted with ``mount_rotation`` (sensor
        frame to rover frame), if the sensor is one: the caster then rasterises the terrain near it."""
        return None

    def optical_axis_cos(self, pattern: np.ndarray) -> np.ndarray | None:
        """Per-ray cosine to the optical axis (depth = range * cos), or ``None`` if depth is not defined."""
        return None

    # ------------------------------------------------------------------ API
    @property
    def observation_space(self) -> spaces.Box:
        return self.encoder.space

    @property
    def n_rays(self) -> int:
        return len(self.caster)

    def reset(self, rng: np.random.Generator) -> None:
        """Start an episode: every later noise draw comes from ``rng`` (the env's ``np_random``), and a
        stateful encoding (``elevation_map.memory``) forgets the last episode's map."""
        self.rng = rng
        self.noise.reset(rng)
        self.encoder.reset()

    def mark_hazard(self, xy: np.ndarray) -> None:
        """The rover reported a drive stopped at world ``xy`` (``WaypointResult.hazard_xy``): the encoding's
        stopped-drive channel, if it has one, shows it from the next observation on."""
        self.encoder.mark_hazard(xy)

    def rays_world(self, position: np.ndarray, rpy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World ray origins and unit directions, ``(N, 3)`` each (new arrays), for a rover pose."""
        rotation = rpy_matrix(rpy)
        rays = self.caster.rays(np.asarray(position, dtype=np.float64) + rotation @ self.mount, rotation)
        return rays[:, :3].copy(), rays[:, 3:].copy()

    def capture(self, position: np.ndarray, rpy: np.ndarray) -> SensorFrame:
        """Cast every ray from the rover pose; noise (if configured) draws from the generator of ``reset``."""
        position = np.array(position, dtype=np.float64)  # copies: the frame keeps the pose it was taken at
        rpy = np.array(rpy, dtype=np.float64)
        rotation = rpy_matrix(rpy)
        origin = position + rotation @ self.mount
        cloud = None
        if self.noise.active:
            t = self.noise.apply(self.caster.cast(origin, rotation))
            # NaN outside [min_range, max_range], in place (t is this frame's own array); ``inf`` (no hit) is
            # outside too, so there is no fake max-range hit
            np.putmask(t, (t < self.cfg.min_range) | (t > self.cfg.max_range), np.float32(np.nan))
        else:  # the caster stops at max_range (== cfg.max_range without noise), NaNs the rest and (heightfield)
            # writes the point cloud as it goes
            t, cloud = self.caster.cast_frame(origin, rotation, self.cfg.min_range, self._mount32)
        return SensorFrame(
            t.reshape(self.image_shape),
            position,
            rpy,
            self.caster.directions,
            self._mount32,
            self.axis_cos,
            cloud,
        )

    def encode(self, frame: SensorFrame) -> np.ndarray:
        """The configured encoding of a frame: float32, finite, inside :attr:`observation_space`."""
        return self.encoder(frame)

    def observe(self, position: np.ndarray, rpy: np.ndarray) -> np.ndarray:
        """``encode(capture(position, rpy))``; the frame stays readable as :attr:`last_frame` (the slope shield
        maps it). Pickling the sensor is safe: the caster drops its scene."""
        self.last_frame = self.capture(position, rpy)
        return self.encoder(self.last_frame)
