"""A GIF of one evaluation episode: the env's frame (top-down map with the driven path beside a
third-person view) with the sensor's view (depth image or elevation map) added on the right.

One frame per waypoint (the env's step), at 4 frames per second: enough to see where the policy went and
what it saw, small enough to log as an artefact of every evaluation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from PIL import Image

__all__ = ["FrameMaker", "sensor_image", "write_gif"]

FRAME_MS = 250


def sensor_image(obs: Any, key: str, height: int) -> np.ndarray | None:
    """An RGB picture of the sensor encoding in ``obs[key]`` (``None`` for point sets, which have no image).

    Images (``(H, W)``, ``(C, H, W)`` or ``(H, W, C)``) show their first channel with the viridis map, NaN
    (no return) black; the picture is scaled to ``height`` pixels with nearest-neighbour sampling.
    """
    if not isinstance(obs, dict) or key not in obs or key == "points":
        return None
    a = np.asarray(obs[key], dtype=np.float64)
    while a.ndim > 2:  # the first channel, whichever axis the channels are on
        a = a[0] if a.shape[0] <= min(a.shape[1:]) else a[..., 0]
    if a.ndim != 2 or a.size == 0:
        return None
    from matplotlib import colormaps

    finite = np.isfinite(a)
    lo, hi = (float(a[finite].min()), float(a[finite].max())) if finite.any() else (0.0, 1.0)
    norm = np.where(finite, (a - lo) / max(hi - lo, 1e-9), 0.0)
    rgb = (colormaps["viridis"](norm)[..., :3] * 255).astype(np.uint8)
    rgb[~finite] = 0
    width = max(1, round(a.shape[1] * height / a.shape[0]))
    return np.asarray(Image.fromarray(rgb).resize((width, height), Image.NEAREST))


class FrameMaker:
    """Builds frames from an env (any render mode: it uses the env's renderer directly)."""

    def __init__(self, env: gym.Env) -> None:
        from diana_lab.envs.render import EnvRenderer

        self.env = env.unwrapped
        self.renderer = EnvRenderer(self.env)

    def frame(self, obs: Any) -> np.ndarray:
        scene = self.renderer.render()
        side = sensor_image(obs, self.env.sensor_key, scene.shape[0])
        if side is None:
            return scene
        return np.concatenate([scene, side], axis=1)

    def close(self) -> None:
        self.renderer.close()


def write_gif(path: Path, frames: list[np.ndarray]) -> Path:
    """Write ``frames`` (equal-sized RGB uint8) as a looping GIF."""
    import imageio.v3 as iio

    if not frames:
        raise ValueError(f"write_gif: no frames for '{path}'")
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), extension=".gif", duration=FRAME_MS, loop=0)
    return path
