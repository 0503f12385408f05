"""Per-call latency of the onboard policy (encoding + inference) on one CPU thread.

``python -m diana_lab.bench`` reports ``policy_latency_ms_p50`` / ``_p99`` from :func:`measure_latency`;
the target on the rover's computer is <= 1 ms median and <= 2 ms p99 for the default depth camera.
Without a recorded cloud the measurement uses :func:`synthetic_cloud`: the trained sensor looking at
flat ground, which returns about as many points as a real frame over open terrain.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from diana_lab.deploy.geometry import pitch_matrix
from diana_lab.deploy.inputs import Pose, check_cloud, check_goal
from diana_lab.deploy.navigator import Navigator
from diana_lab.deploy.spec import SensorSpec

__all__ = ["measure_latency", "synthetic_cloud"]


def _pattern(sensor: SensorSpec) -> np.ndarray:
    """Unit ray directions ``(rows * cols, 3)`` of the trained sensor in its body frame."""
    rows, cols = sensor.image_shape
    if sensor.type == "depth_camera":
        u = ((np.arange(cols) + 0.5) / cols * 2.0 - 1.0) * np.tan(np.radians(sensor.hfov_deg) / 2.0)
        v = ((np.arange(rows) + 0.5) / rows * 2.0 - 1.0) * np.tan(np.radians(sensor.vfov_deg) / 2.0)
        uu, vv = np.meshgrid(u, v)
        d = np.stack([np.ones_like(uu), -uu, -vv], axis=-1)
    else:
        if rows == 1:
            el = np.radians([(sensor.vfov_min_deg + sensor.vfov_max_deg) / 2.0])
        else:
            el = np.radians(np.linspace(sensor.vfov_max_deg, sensor.vfov_min_deg, rows))
        az = np.pi - (np.arange(cols) + 0.5) * (2.0 * np.pi / cols)
        e, a = np.meshgrid(el, az, indexing="ij")
        d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)
    d = d.reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def synthetic_cloud(sensor: SensorSpec, ground_z: float = -0.1) -> np.ndarray:
    """The sensor-frame returns of flat ground ``ground_z`` metres below the rover origin (rover level)."""
    d_sensor = _pattern(sensor)
    d_rover = d_sensor @ pitch_matrix(sensor.mount_pitch).T
    height = sensor.mount_xyz[2] - ground_z
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d_rover[:, 2] < -1e-6, height / -d_rover[:, 2], np.inf)
    hit = (t >= sensor.min_range) & (t <= sensor.max_range)
    return d_sensor[hit] * t[hit, None]


def measure_latency(
    navigator: Navigator, n: int = 1000, warmup: int = 50, pose: Any = None, goal: Any = None, cloud: Any = None
) -> dict[str, float]:
    """Time ``n`` calls of :meth:`Navigator.next_waypoint` (after ``warmup`` untimed ones), in milliseconds.

    Runs on one onnxruntime thread: a navigator built with more is re-opened with one. Returns ``p50``,
    ``p99`` and ``mean`` of the whole call, ``encode_p50`` (goal vector + sensor encoding) and
    ``infer_p50`` (the ONNX session, and the slope shield when the sidecar asks for it), and ``n``.
    """
    if n <= 0:
        raise ValueError(f"n: expected a positive number of calls, got {n}")
    nav = navigator if navigator.threads == 1 else Navigator(navigator.spec, navigator.model_path, threads=1)
    pose = Pose(0.0, 0.0, 0.0, 0.02, -0.03, 0.3) if pose is None else Pose.of(pose)
    goal = np.array([12.0, -5.0]) if goal is None else goal
    cloud = check_cloud(synthetic_cloud(nav.spec.sensor) if cloud is None else cloud)
    total = np.empty(n)
    encode = np.empty(n)
    goal = check_goal(goal)
    for i in range(-warmup, n):
        frame = cloud.copy()  # a new cloud every call, as from a sensor (nothing cached from the last one)
        t0 = time.perf_counter()  # Navigator.next_waypoint, step by step
        p, pts = Pose.of(pose), check_cloud(frame)
        obs = nav._observation(p, goal, pts)
        t1 = time.perf_counter()
        nav._waypoint(p, nav._decide(p, obs, pts, goal))
        t2 = time.perf_counter()
        if i >= 0:
            total[i], encode[i] = t2 - t0, t1 - t0
    ms = 1e3
    return {
        "p50": float(np.percentile(total, 50) * ms),
        "p99": float(np.percentile(total, 99) * ms),
        "mean": float(total.mean() * ms),
        "encode_p50": float(np.percentile(encode, 50) * ms),
        "infer_p50": float(np.percentile(total - encode, 50) * ms),
        "n": float(n),
    }
