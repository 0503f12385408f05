"""Sensor figures: a depth frame to its encoded observation, against PyBullet's ray test and TinyRenderer.

All on one thread, over the same random rover poses (standing on the terrain of the configured world) and
the same rays: ``sensor.rays_world`` gives PyBullet exactly the rays our caster casts. Our figure includes
the point cloud in the rover frame and the encoding (the issue's "cast + point cloud + depth_image");
PyBullet's include only the cast (``rayTestBatch``, with the Python list conversion any caller pays) or the
render and the depth-buffer conversion, so the comparison favours the anchors. Our casts use the run's
``sensor.backend`` (``heightfield`` by default, ``sensor.backend=open3d`` for the reference); the figures'
notes name it.
"""

from __future__ import annotations

import itertools
import math
import time
from typing import Any

import numpy as np

from diana_lab.benchmarks.core import BenchContext, Figure, Target, figure_from_samples, measurement, repeat

__all__ = ["TinyRendererDepth", "elevation_map", "sensor_112", "sensor_vs_pybullet"]

SENSOR_TARGET = Target("<=", 0.3)
SPEEDUP_TARGET = Target(">=", 30.0)
ELEVATION_TARGET = Target("<=", 1.0)
SENSOR_112_TARGET = Target("<=", 2.0)
PYBULLET_KEYS = {"heightfield": "sensor_ms_pybullet_raytest", "mesh": "sensor_ms_pybullet_raytest_mesh"}
TINY_SIZE = 64  # the TinyRenderer anchor renders 64 x 64 pixels


def _sensor(ctx: BenchContext, *overrides: str) -> Any:
    from diana_lab import config as C

    sensor = C.build(ctx.typed("sensor", *overrides), ctx.world)
    sensor.reset(np.random.default_rng(ctx.seed))
    return sensor


def _batches(ctx: BenchContext, size: int) -> Any:
    """Successive, non-overlapping (cyclic) batches of ``size`` poses: each repeat sees new poses."""
    poses = ctx.poses
    for i in itertools.count():
        yield [poses[(i * size + k) % len(poses)] for k in range(size)]


def _ms_per(seconds: float, count: int) -> float:
    return seconds / count * 1e3


def _caster(sensor: Any) -> str:
    """What casts the sensor's rays, for a figure's note."""
    if sensor.caster.backend == "open3d":
        return "open3d RaycastingScene"
    return "heightfield ray marcher (numba)"


class TinyRendererDepth:
    """A depth image from PyBullet's software renderer, from the pose and field of view of a depth camera.

    Rendered in an existing PyBullet client (here the heightfield scene of the ray-test reference); the
    OpenGL depth buffer is converted to metres along the optical axis, as a depth camera reports.
    """

    def __init__(self, client: int, cam: Any, width: int = TINY_SIZE, height: int = TINY_SIZE) -> None:
        import pybullet as p

        from diana_lab.core.rotations import pitch_matrix

        self._p, self.client, self.cam = p, client, cam
        self.width, self.height = width, height
        self.near, self.far = float(cam.min_range), float(cam.max_range)
        self._mount = np.asarray(cam.mount_xyz, dtype=np.float64)
        self._mount_rot = pitch_matrix(math.radians(cam.mount_pitch_deg))
        aspect = math.tan(math.radians(cam.hfov_deg) / 2) / math.tan(math.radians(cam.vfov_deg) / 2)
        self._proj = p.computeProjectionMatrixFOV(cam.vfov_deg, aspect, self.near, self.far)

    def render(self, position: np.ndarray, rpy: np.ndarray) -> np.ndarray:
        from diana_lab.core.rotations import rpy_matrix

        p = self._p
        rot = rpy_matrix(rpy)
        eye = np.asarray(position, dtype=np.float64) + rot @ self._mount
        cam = rot @ self._mount_rot  # columns: optical axis (x), left (y), up (z) in the world
        view = p.computeViewMatrix(eye.tolist(), (eye + cam[:, 0]).tolist(), cam[:, 2].tolist())
        img = p.getCameraImage(
            self.width,
            self.height,
            view,
            self._proj,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self.client,
        )
        buf = np.asarray(img[3], dtype=np.float32).reshape(self.height, self.width)
        n, f = self.near, self.far
        return f * n / (f - (f - n) * buf)


@measurement(
    "sensor_ms",
    "sensor_ms_pybullet_raytest",
    "sensor_ms_pybullet_raytest_mesh",
    "sensor_speedup",
    "sensor_ms_tinyrenderer",
)
def sensor_vs_pybullet(ctx: BenchContext) -> list[Figure]:
    """Interleaved per repeat over one batch of poses: our frame -> point cloud and ``depth_image``, then PyBullet's ray
    test of the same rays (heightfield terrain, then the scene as one mesh), then TinyRenderer."""
    from diana_lab.sensing.pybullet_reference import PyBulletRayCaster

    sensor = _sensor(ctx, "sensor=depth_camera", "sensor.encoding=depth_image")
    max_range = float(sensor.cfg.max_range)
    per, inner = ctx.size(24, 4), 4  # PyBullet frames per repeat; ours loop the batch `inner` times
    batches = _batches(ctx, per)
    refs = {t: PyBulletRayCaster(ctx.world, terrain=t, num_threads=1) for t in ("heightfield", "mesh")}
    tiny = TinyRendererDepth(refs["heightfield"].client, sensor.cfg)
    agreement: list[float] = []

    def sample() -> dict[str, float]:
        batch = next(batches)
        rays = [sensor.rays_world(pos, rpy) for pos, rpy in batch]
        t0 = time.perf_counter()
        for _ in range(inner):
            for pos, rpy in batch:  # the frame, its point cloud (which depth_image itself never needs) and encoding
                frame = sensor.capture(pos, rpy)
                frame.points  # noqa: B018 (computed and cached on access)
                sensor.encode(frame)
        out = {"sensor_ms": _ms_per(time.perf_counter() - t0, per * inner)}
        for terrain, key in PYBULLET_KEYS.items():
            t0 = time.perf_counter()
            ranges = [refs[terrain].cast(o, d, max_range) for o, d in rays]
            out[key] = _ms_per(time.perf_counter() - t0, per)
            if terrain == "mesh":  # the same rays must give the same ranges, or the comparison is moot
                ours = sensor.capture(*batch[0]).ranges.ravel()
                both = np.isfinite(ours) & np.isfinite(ranges[0])
                agreement.append(float(np.max(np.abs(ours[both] - ranges[0][both]), initial=0.0)))
        t0 = time.perf_counter()
        for pos, rpy in batch:
            tiny.render(pos, rpy)
        out["sensor_ms_tinyrenderer"] = _ms_per(time.perf_counter() - t0, per)
        out["sensor_speedup"] = out["sensor_ms_pybullet_raytest"] / out["sensor_ms"]
        return out

    try:
        samples = repeat(sample, ctx.repeats)
    finally:
        for ref in refs.values():
            ref.close()

    def col(key: str) -> list[float]:
        return [s[key] for s in samples]

    rays = f"{sensor.n_rays} rays"
    ours = figure_from_samples(
        "sensor_ms",
        "ms",
        col("sensor_ms"),
        batch=f"{per * inner} frames ({per} poses x {inner})",
        target=SENSOR_TARGET,
        note=f"{_caster(sensor)}, 1 thread, {sensor.image_shape[1]}x{sensor.image_shape[0]} ({rays}) -> point cloud "
        "+ depth_image",
    )
    hf = figure_from_samples(
        "sensor_ms_pybullet_raytest",
        "ms",
        col("sensor_ms_pybullet_raytest"),
        batch=f"{per} frames",
        note=f"PyBullet rayTestBatch, 1 thread, heightfield terrain, same {rays}, cast only",
    )
    mesh = figure_from_samples(
        "sensor_ms_pybullet_raytest_mesh",
        "ms",
        col("sensor_ms_pybullet_raytest_mesh"),
        batch=f"{per} frames",
        note=f"PyBullet rayTestBatch, 1 thread, scene as one concave mesh, same {rays}, cast only",
        extra={"max_range_diff_m": max(agreement) if agreement else None},
    )
    speedup = figure_from_samples(
        "sensor_speedup",
        "x",
        col("sensor_speedup"),
        batch="per repeat: raytest ms / sensor ms over the same poses",
        target=SPEEDUP_TARGET,
        note="sensor_ms_pybullet_raytest / sensor_ms",
    )
    tiny_fig = figure_from_samples(
        "sensor_ms_tinyrenderer",
        "ms",
        col("sensor_ms_tinyrenderer"),
        batch=f"{per} frames",
        note=f"PyBullet TinyRenderer {TINY_SIZE}x{TINY_SIZE} depth (same pose and FOV), heightfield scene",
    )
    ratio = tiny_fig.value / ours.value if tiny_fig.value and ours.value else None
    anchor = {"name": "PyBullet rayTestBatch (heightfield)", "value": hf.value, "ratio": speedup.value}
    ours.anchor = anchor
    tiny_fig.anchor = {"name": "sensor_ms", "ratio": ratio}
    return [ours, hf, mesh, speedup, tiny_fig]


def _frame_figure(
    ctx: BenchContext, key: str, overrides: tuple[str, ...], target: Target, frames: int, what: str
) -> Figure:
    """ms per frame -> encoded observation (and, as ``capture_ms``, the cast part alone)."""
    sensor = _sensor(ctx, *overrides)
    batches = _batches(ctx, frames)

    def sample() -> tuple[float, float]:
        batch = next(batches)
        t0 = time.perf_counter()
        for pos, rpy in batch:
            sensor.observe(pos, rpy)
        observe = time.perf_counter() - t0
        t0 = time.perf_counter()
        for pos, rpy in batch:
            sensor.capture(pos, rpy)
        return _ms_per(observe, frames), _ms_per(time.perf_counter() - t0, frames)

    samples = repeat(sample, ctx.repeats)
    capture = figure_from_samples("capture", "ms", [s[1] for s in samples])
    return figure_from_samples(
        key,
        "ms",
        [s[0] for s in samples],
        batch=f"{frames} frames",
        target=target,
        note=f"{what}, {_caster(sensor)}, 1 thread ({sensor.n_rays} rays)",
        extra={"capture_ms": capture.value},
    )


@measurement("elevation_map_ms")
def elevation_map(ctx: BenchContext) -> list[Figure]:
    frames = ctx.size(200, 40)
    overrides = ("sensor=depth_camera", "sensor.encoding=elevation_map")
    what = "64x48 depth frame -> elevation_map (levelled, voxel 0.1 m, 0.25 m cells)"
    return [_frame_figure(ctx, "elevation_map_ms", overrides, ELEVATION_TARGET, frames, what)]


@measurement("sensor_ms_112")
def sensor_112(ctx: BenchContext) -> list[Figure]:
    frames = ctx.size(200, 40)
    overrides = ("sensor=depth_camera_paper", "sensor.encoding=depth_image")
    what = "112x112 depth frame (paper preset) -> depth_image"
    return [_frame_figure(ctx, "sensor_ms_112", overrides, SENSOR_112_TARGET, frames, what)]
