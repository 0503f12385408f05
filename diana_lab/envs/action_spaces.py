"""From the agent's action to the next waypoint (paper section 5.1).

``square``: the normalised action in [-1, 1]^2 scales to a square of side ``size`` centred on the rover.
``circle``: Shirley and Chiu's concentric mapping takes the square onto the disc of radius ``radius``
one-to-one and continuously, so every point of the disc is reachable and no part of the action space is
wasted (clipping or ``(r cos t, r sin t)`` polar mappings would squash or duplicate actions). ``discrete``:
the action is the index of one of a fixed table of candidate offsets (bearings x distances, see
:class:`~diana_lab.config.env.ActionSpaceConfig`), for a categorical policy that picks one mode of a
multimodal expert instead of averaging them. ``frame=rover`` turns the offset by the rover's (estimated)
heading; ``frame=world`` keeps the map's axes, as the paper did.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces

from diana_lab.config.env import ActionSpaceConfig
from diana_lab.core.candidates import candidate_offsets, turned
from diana_lab.envs import ActionError  # defined there, free of imports: diana_lab.ActionError

QUARTER_PI = math.pi / 4.0
TIE_M2 = 1e-9  # squared distances (m^2) this close count as a tie in WaypointMapping.action_for


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
        self.extent = cfg.extent
        self.discrete = cfg.shape == "discrete"
        self._table = np.zeros((0, 2))
        if self.discrete:
            self._table = candidate_offsets(cfg.headings, cfg.distances)
            self._table.flags.writeable = False
        self._rows = [(float(x), float(y)) for x, y in self._table]  # scalars for the per-step lookup

    @property
    def space(self) -> spaces.Space:
        """The gymnasium action space: ``Box(-1, 1, (2,))`` or ``Discrete(n)`` over the candidates."""
        if self.discrete:
            return spaces.Discrete(len(self._rows))
        return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    @property
    def candidates(self) -> np.ndarray:
        """The discrete action space's ``(n, 2)`` candidate offsets in the action frame (read-only); row ``k``
        is action ``k`` (see :func:`candidate_offsets`)."""
        if not self.discrete:
            raise ValueError(f"action_space.shape={self.cfg.shape}: only a discrete action space has candidates")
        return self._table

    def world_offsets(self, yaw: float) -> np.ndarray:
        """Every candidate's world-frame offset from the rover, ``(n, 2)`` (row ``k``: ``offset(k, yaw)``)."""
        table = self.candidates
        if self.cfg.frame != "rover":
            return table.copy()
        return turned(table, yaw)

    def check(self, action: Any) -> Any:
        """Validate an action and return it as the mapping uses it, or raise :class:`ActionError`.

        Continuous: NaN/inf or a wrong shape raise; large values are clipped (an ``np.ndarray`` of 2). Discrete:
        one integer (Python, numpy, or an integer array of one element) in ``[0, n)``, returned as an ``int``;
        floats are refused rather than rounded, since a float index means a continuous policy on this env.
        """
        return self._check_index(action) if self.discrete else self._check_box(action)

    @staticmethod
    def _check_box(action: np.ndarray) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (2,):
            raise ActionError(f"action: expected shape (2,), got {a.shape}")
        x, y = a.tolist()  # two numbers: math and min/max cost a fraction of np.isfinite and np.clip
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ActionError(f"action: expected finite values in [-1, 1], got {a.tolist()}")
        return np.array([min(max(x, -1.0), 1.0), min(max(y, -1.0), 1.0)])

    def _check_index(self, action: Any) -> int:
        n = len(self._rows)
        if isinstance(action, int | np.integer) and not isinstance(action, bool):
            k = int(action)
        else:
            a = np.asarray(action)
            if a.size != 1 or a.ndim > 1 or not np.issubdtype(a.dtype, np.integer):
                raise ActionError(
                    f"action: expected one integer candidate index in [0, {n}) (action_space.shape=discrete), "
                    f"got {a.tolist()!r} (dtype {a.dtype}, shape {a.shape})"
                )
            k = int(a.reshape(()))
        if not 0 <= k < n:
            raise ActionError(f"action: candidate index {k} is outside [0, {n}) (action_space.shape=discrete)")
        return k

    def offset(self, action: Any, yaw: float) -> np.ndarray:
        """World-frame offset from the rover to the waypoint."""
        if self.discrete:
            x, y = self._rows[self._check_index(action)]
        else:
            a = self._check_box(action)
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
        """The action whose waypoint is ``offset`` away from the rover (clipped to the shape).

        Discrete: the index of the nearest candidate in the action frame, as an int64 array of shape ``()``
        (what gymnasium's ``Discrete`` and SB3 take); ties go to the lowest index.
        """
        o = np.asarray(offset, dtype=np.float64)
        if self.cfg.frame == "rover":
            c, s = math.cos(yaw), math.sin(yaw)
            o = np.array([c * o[0] + s * o[1], -s * o[0] + c * o[1]])
        if self.discrete:
            diff = self._table - o
            d2 = np.einsum("ij,ij->i", diff, diff)
            # ties within rounding (a zero offset is 1 m from every candidate of the first ring) -> lowest index
            return np.asarray(np.flatnonzero(d2 <= d2.min() + TIE_M2)[0], dtype=np.int64)
        o = o / self.extent
        if self.cfg.shape == "circle":
            norm = float(np.hypot(*o))
            if norm > 1.0:
                o = o / norm
            return np.clip(disc_to_square(o), -1.0, 1.0)
        return np.clip(o, -1.0, 1.0)
