"""The sidecar's contents from a training's config groups: what the onboard runtime needs to know besides the
graph (its sensor, encoding and action space, the goal's bounds and the observation statistics).

No torch here: :mod:`diana_lab.deploy.export` writes the sidecar with the graph, and ``python -m diana_lab.export``
checks a command line's groups against a sidecar (:mod:`diana_lab.deploy.command`) with the same builders. The
onboard runtime reads the result with :mod:`diana_lab.deploy.spec` alone.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

import diana_lab
from diana_lab.config import ConfigError
from diana_lab.config.env import ActionSpaceConfig, EpisodeConfig
from diana_lab.config.sensing import DepthCameraConfig, Lidar3dConfig, SensorConfig
from diana_lab.deploy.spec import ActionSpec, EncodingSpec, PolicySpec, SensorSpec

__all__ = ["action_spec", "encoding_spec", "expected_shape", "observation_statistics", "policy_spec", "sensor_spec"]


def expected_shape(sensor: SensorConfig) -> tuple[int, ...]:
    """The encoding's tensor shape for a sensor config (without building the sensor or a world)."""
    if sensor.encoding == "elevation_map":
        return (sensor.elevation_map.channels, *sensor.elevation_map.shape)
    if sensor.encoding == "points":
        return (sensor.points.n_points, 4)
    if isinstance(sensor, DepthCameraConfig):
        return (1, sensor.height, sensor.width)
    if isinstance(sensor, Lidar3dConfig):
        return (1, sensor.beams, sensor.columns)
    raise ConfigError(f"sensor: cannot export a policy for sensor type {type(sensor).__name__}")


def sensor_spec(sensor: SensorConfig) -> SensorSpec:
    common = {
        "mount_xyz": tuple(float(v) for v in sensor.mount_xyz),
        "mount_pitch_deg": float(sensor.mount_pitch_deg),
        "min_range": float(sensor.min_range),
        "max_range": float(sensor.max_range),
    }
    if isinstance(sensor, DepthCameraConfig):
        return SensorSpec(
            type="depth_camera",
            width=sensor.width,
            height=sensor.height,
            hfov_deg=float(sensor.hfov_deg),
            vfov_deg=float(sensor.vfov_deg),
            **common,
        )
    if isinstance(sensor, Lidar3dConfig):
        return SensorSpec(
            type="lidar3d",
            beams=sensor.beams,
            vfov_min_deg=float(sensor.vfov_min_deg),
            vfov_max_deg=float(sensor.vfov_max_deg),
            columns=sensor.columns,
            **common,
        )
    raise ConfigError(f"sensor: cannot export a policy for sensor type {type(sensor).__name__}")


def encoding_spec(sensor: SensorConfig) -> EncodingSpec:
    from diana_lab.sensing.encoders import NO_RETURN, UNKNOWN_HEIGHT

    shape = expected_shape(sensor)
    if sensor.encoding == "depth_image":
        params: dict[str, Any] = {"no_return": NO_RETURN}
    elif sensor.encoding == "elevation_map":
        params = {**dataclasses.asdict(sensor.elevation_map), "unknown_height": UNKNOWN_HEIGHT}
    else:
        scale = float(sensor.max_range) + float(np.linalg.norm(sensor.mount_xyz))  # as make_encoder
        params = {**dataclasses.asdict(sensor.points), "scale": scale}
    return EncodingSpec(sensor.encoding, shape, params)


def action_spec(action: ActionSpaceConfig) -> ActionSpec:
    discrete = action.shape == "discrete"
    return ActionSpec(
        shape=action.shape,
        size=float(action.size),
        radius=float(action.radius),
        frame=action.frame,
        min_distance=float(action.min_distance),
        headings=int(action.headings) if discrete else None,
        distances=tuple(float(d) for d in action.distances) if discrete else None,
    )


def observation_statistics(
    vecnormalize: Any, keys: tuple[str, ...]
) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], float]:
    """``{key: (mean, std)}`` of the observation keys VecNormalize normalised, and its ``clip_obs``."""
    if vecnormalize is None or not getattr(vecnormalize, "norm_obs", False):
        return {}, math.inf
    rms = vecnormalize.obs_rms
    norm_keys = vecnormalize.norm_obs_keys or list(keys)
    out = {}
    for key in norm_keys:
        stats = rms[key] if isinstance(rms, dict) else rms
        out[key] = (
            np.asarray(stats.mean, dtype=np.float64),
            np.sqrt(np.asarray(stats.var, dtype=np.float64) + vecnormalize.epsilon),
        )
    return out, float(vecnormalize.clip_obs)


def policy_spec(
    model: Any,
    sensor: SensorConfig,
    action: ActionSpaceConfig,
    episode: EpisodeConfig,
    normalization: dict[str, Any],
    source: dict[str, Any],
    opset: int,
    shield: dict[str, Any] | None = None,
) -> PolicySpec:
    """The sidecar of a model trained with these ``sensor``, ``action_space`` and ``episode`` groups (and the
    slope shield's settings, ``ShieldSettings`` as a dict, when the runtime is to drive behind it)."""
    enc = encoding_spec(sensor)
    goal_space = model.observation_space["goal"]
    return PolicySpec(
        sensor=sensor_spec(sensor),
        encoding=enc,
        action_space=action_spec(action),
        distance_scale=float(episode.distance_scale),
        goal_low=tuple(float(v) for v in np.asarray(goal_space.low, dtype=np.float32)),
        goal_high=tuple(float(v) for v in np.asarray(goal_space.high, dtype=np.float32)),
        inputs={"goal": [-1, 7], enc.name: [-1, *enc.shape]},
        outputs=(
            {"offset": [-1, 2], "action": [-1], "logits": [-1, int(model.action_space.n)]}
            if action.shape == "discrete"
            else {"offset": [-1, 2], "action": [-1, 2]}
        ),
        normalization=normalization,
        source=source,
        diana_lab_version=diana_lab.__version__,
        opset=opset,
        shield=shield,
    )
