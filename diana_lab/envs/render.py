"""Frames for videos: a top-down hillshade map with the driven path, beside a third-person view.

The map background is shaded once per world; each frame only draws the path, the goal and the rover with PIL.
The third-person view comes from PyBullet's TinyRenderer through the dynamics' scene (the kinematic model
builds that scene on first use). ``human`` mode opens the PyBullet GUI instead when a display exists.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, ImageDraw

if TYPE_CHECKING:
    from diana_lab.envs.rover_nav import RoverNavEnv
    from diana_lab.sim.world import World

MAP_PIXELS = 320
VIEW_SIZE = (320, 320)


def hillshade(world: World, pixels: int = MAP_PIXELS) -> np.ndarray:
    """An RGB hillshade of the terrain (north up), with obstacles drawn dark; ``(H, W, 3)`` uint8."""
    from matplotlib import colormaps
    from matplotlib.colors import LightSource

    h = world.terrain.heights[::-1]  # image rows run north to south
    span = float(np.ptp(h))
    if span < 1e-3:  # flat: shading and a colour ramp have nothing to show; use one mid tone of the ramp
        rgb = np.broadcast_to(np.asarray(colormaps["copper"](0.6))[:3], (*h.shape, 3))
    else:
        ls = LightSource(azdeg=315, altdeg=45)
        rgb = ls.shade(
            h,
            cmap=colormaps["copper"],
            vert_exag=30.0 / span,
            blend_mode="soft",
            dx=world.terrain.dx,
            dy=world.terrain.dy,
        )[..., :3]
    img = Image.fromarray((rgb * 255).astype(np.uint8))
    ny, nx = world.terrain.shape
    scale = pixels / max(nx, ny)
    img = img.resize((max(1, round(nx * scale)), max(1, round(ny * scale))), Image.BILINEAR)
    arr = np.asarray(img).copy()
    om = world.obstacle_map.height[::-1] > 0.02
    if om.any():
        mask = np.asarray(Image.fromarray(om.astype(np.uint8) * 255).resize(img.size, Image.NEAREST)) > 0
        arr[mask] = (40, 30, 25)
    return arr


class TopDownMap:
    """Converts world coordinates to pixels of the hillshade and draws on copies of it."""

    def __init__(self, world: World, pixels: int = MAP_PIXELS) -> None:
        self.world = world
        self.background = hillshade(world, pixels)
        x0, x1, y0, y1 = world.bounds
        self._x0, self._y1 = x0, y1
        self._sx = (self.background.shape[1] - 1) / (x1 - x0)
        self._sy = (self.background.shape[0] - 1) / (y1 - y0)

    def to_px(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([(xy[:, 0] - self._x0) * self._sx, (self._y1 - xy[:, 1]) * self._sy])

    def draw(
        self,
        paths: list[tuple[np.ndarray, tuple[int, int, int]]],
        start: np.ndarray | None = None,
        goal: np.ndarray | None = None,
        rover: tuple[np.ndarray, float] | None = None,
        goal_radius: float = 0.5,
    ) -> Image.Image:
        img = Image.fromarray(self.background.copy())
        d = ImageDraw.Draw(img)
        for path, colour in paths:
            if len(path) > 1:
                d.line([tuple(p) for p in self.to_px(path)], fill=colour, width=2)
        if start is not None:
            sx, sy = self.to_px(start)[0]
            d.rectangle([sx - 3, sy - 3, sx + 3, sy + 3], outline=(255, 255, 255), width=2)
        if goal is not None:
            gx, gy = self.to_px(goal)[0]
            r = max(3.0, goal_radius * self._sx)
            d.ellipse([gx - r, gy - r, gx + r, gy + r], outline=(60, 220, 60), width=2)
        if rover is not None:
            (px, py), yaw = self.to_px(rover[0])[0], rover[1]
            tip = (px + 8 * math.cos(yaw), py - 8 * math.sin(yaw))
            left = (px + 5 * math.cos(yaw + 2.5), py - 5 * math.sin(yaw + 2.5))
            right = (px + 5 * math.cos(yaw - 2.5), py - 5 * math.sin(yaw - 2.5))
            d.polygon([tip, left, right], fill=(40, 160, 255))
        return img


class EnvRenderer:
    def __init__(self, env: RoverNavEnv, gui: bool = False) -> None:
        self.env = env
        self.map = TopDownMap(env.world)
        self.gui = gui and bool(os.environ.get("DISPLAY"))

    def third_person(self) -> np.ndarray:
        import pybullet as p

        scene = self.env.dynamics.scene()
        st = self.env.dynamics.state
        view = p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=st.position.tolist(),
            distance=3.0,
            yaw=math.degrees(st.yaw) - 90.0,
            pitch=-25.0,
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=scene.client,
        )
        proj = p.computeProjectionMatrixFOV(60.0, VIEW_SIZE[0] / VIEW_SIZE[1], 0.1, 60.0, physicsClientId=scene.client)
        _, _, rgba, _, _ = p.getCameraImage(
            VIEW_SIZE[0], VIEW_SIZE[1], view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=scene.client
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(VIEW_SIZE[1], VIEW_SIZE[0], 4)[..., :3]

    def render(self) -> np.ndarray:
        env = self.env
        st = env.dynamics.state
        top = self.map.draw(
            [(env.trail, (255, 80, 40))],
            env._episode.start,
            env.goal,
            (st.xy, st.yaw),
            env.episode_cfg.goal_tolerance,
        )
        top = np.asarray(top.resize((VIEW_SIZE[0], round(top.height * VIEW_SIZE[0] / top.width))))
        side = self.third_person()
        height = max(top.shape[0], side.shape[0])
        frame = np.zeros((height, top.shape[1] + side.shape[1], 3), dtype=np.uint8)
        frame[: top.shape[0], : top.shape[1]] = top
        frame[: side.shape[0], top.shape[1] :] = side
        return frame

    def close(self) -> None:
        pass
