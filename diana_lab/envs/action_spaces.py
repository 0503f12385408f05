"""From the agent's normalised action in [-1, 1]^2 to the next waypoint (paper section 5.1).

``square``: the action scales to a square of side ``size`` centred on the rover. ``circle``: Shirley and
Chiu's concentric mapping takes the square onto the disc of radius ``radius`` one-to-one and continuously,
so every point of the disc is reachable and no part of the action space is wasted (clipping or
``(r cos t, r sin t)`` polar mappings would squash or duplicate actions). ``frame=rover`` turns the offset by
the rover's (estimated) heading; ``frame=world`` keeps the map's axes, as the paper did.
"""

from __future__ import annotations

import math

import numpy as np

from diana_lab.config.env import ActionSpaceConfig

QUARTER_PI = math.pi / 4.0


class ActionError(ValueError):
    """An action the env cannot execute (wrong shape, NaN or infinite values)."""


def square_to_disc(a: np.ndarray) -> np.ndarray:
    """Shirley-Chiu concentric map of points in [-1, 1]^2 onto the unit disc (vectorised over ``(..., 2)``)."""
    a = np.asarray(a, dtype=np.float64)
    x, y = a[..., 0], a[..., 1]
    use_x = np.abs(x) > np.abs(y)
    safe_x = np.where(x == 0, 1.0, x)
    safe_y = np.where(y == 0, 1.0, y)
    r = np.where(use_x, x, y)
    theta = np.where(use_x, QUARTER_PI * (y / safe_x), np.pi / 2 - QUARTER_PI * (x / safe_y))
    theta = np.where((x == 0) & (y == 0), 0.0, theta)
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=-1)


def disc_to_square(p: np.ndarray) -> np.ndarray:
    """Inverse of :func:`square_to_disc` (points on the unit disc back to [-1, 1]^2)."""
    p = np.asarray(p, dtype=np.float64)
    u, v = p[..., 0], p[..., 1]
    r = np.hypot(u, v)
    phi = np.arctan2(v, u)  # (-pi, pi]
    phi = np.where(phi < -QUARTER_PI, phi + 2 * np.pi, phi)  # [-pi/4, 7pi/4)
    # four wedges: right (|x|>|y|, x>0), top, left, bottom
    x = np.select(
        [phi < QUARTER_PI, phi < 3 * QUARTER_PI, phi < 5 * QUARTER_PI],
        [r, (np.pi / 2 - phi) * r / QUARTER_PI, -r],
        default=(phi - 3 * np.pi / 2) * r / QUARTER_PI,
    )
    y = np.select(
        [phi < QUARTER_PI, phi < 3 * QUARTER_PI, phi < 5 * QUARTER_PI],
        [phi * r / QUARTER_PI, r, -(phi - np.pi) * r / QUARTER_PI],
        default=-r,
    )
    return np.stack([x, y], axis=-1)


class WaypointMapping:
    """Maps actions to waypoints (and back, for scripted policies and the deployment runtime)."""

    def __init__(self, cfg: ActionSpaceConfig) -> None:
        self.cfg = cfg
        self.extent = cfg.size / 2.0 if cfg.shape == "square" else cfg.radius

    @staticmethod
    def check(action: np.ndarray) -> np.ndarray:
        """Validate an action: NaN/inf or a wrong shape raise :class:`ActionError`; large values are clipped."""
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (2,):
            raise ActionError(f"action: expected shape (2,), got {a.shape}")
        x, y = a.tolist()  # two numbers: math and min/max cost a fraction of np.isfinite and np.clip
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ActionError(f"action: expected finite values in [-1, 1], got {a.tolist()}")
        return np.array([min(max(x, -1.0), 1.0), min(max(y, -1.0), 1.0)])

    def offset(self, action: np.ndarray, yaw: float) -> np.ndarray:
        """World-frame offset from the rover to the waypoint."""
        a = self.check(action)
        if self.cfg.shape == "circle":
            a = square_to_disc(a)
        x, y = a[0] * self.extent, a[1] * self.extent  # on scalars: one waypoint per env step
        d = self.cfg.min_distance
        if d > 0:
            norm = float(np.hypot(x, y))
            if norm < d:
                x, y = (x / norm * d, y / norm * d) if norm > 1e-9 else (d, 0.0)
        if self.cfg.frame == "rover":
            c, s = math.cos(yaw), math.sin(yaw)
            x, y = c * x - s * y, s * x + c * y
        return np.array([x, y], dtype=np.float64)

    def action_for(self, offset: np.ndarray, yaw: float) -> np.ndarray:
        """The action whose waypoint is ``offset`` away from the rover (clipped to the shape)."""
        o = np.asarray(offset, dtype=np.float64)
        if self.cfg.frame == "rover":
            c, s = math.cos(yaw), math.sin(yaw)
            o = np.array([c * o[0] + s * o[1], -s * o[0] + c * o[1]])
        o = o / self.extent
        if self.cfg.shape == "circle":
            norm = float(np.hypot(*o))
            if norm > 1.0:
                o = o / norm
            return np.clip(disc_to_square(o), -1.0, 1.0)
        return np.clip(o, -1.0, 1.0)
