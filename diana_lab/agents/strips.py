"""``elevation_encoder: strips``: the map read along every candidate heading by one shared network.

Why: with a discrete action space the policy's choice is which candidate waypoint to drive to, and whether a
candidate is safe depends on the ground along its drive, the same way for every heading. A CNN or an MLP over
the rover-centred map must learn that rule again for each of the candidates, from the few of its failures
each one sees; here it is learnt once. For every heading of the action space, a strip of the map along it (the
cells under the rover's track: ``lateral`` offsets either side of the heading's line, every ``step`` metres out
to ``reach``) is gathered with fixed indices, and one small network scores each strip, with the heading's angle
to the goal and the goal's distance, into one logit per candidate distance; a circular convolution over the
headings lets neighbouring headings inform each other (round an obstacle on the left or the right). The
weights are shared across headings, so the network is equivariant to turning: what it learns of a slope ahead
holds for a slope behind. On the Mars yard a greedy step with a perfect safety check of each candidate reaches
almost every goal (docs/batched.md): the candidates' safety is what needs learning.

The encoder's output is the candidates' logits (heading-major, the action space's own order) followed by
pooled features for the value function; :func:`init_logit_head` starts SB3's action head as the identity on the
logits, so the policy's scores are the network's from the first update.

Everything is gathers, linear layers and a convolution: it exports to ONNX and runs in the onboard runtime.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

__all__ = ["CandidateStrips", "init_logit_head", "strip_indices"]


def strip_indices(
    rows: int,
    cols: int,
    cell_size: float,
    extent_forward: float,
    extent_side: float,
    headings: int,
    lateral: Sequence[float],
    step: float,
    reach: float,
) -> np.ndarray:
    """``(headings, len(lateral) * n_steps)`` flat indices into the ``rows x cols`` map of the points of each
    heading's strip (rover frame: heading ``k`` at ``2 pi k / headings`` counter-clockwise from forward; point
    ``(r, l)`` at ``r`` metres along it and ``l`` to its left), ``rows * cols`` where a point lies off the map."""
    radii = step * np.arange(1, int(math.floor(reach / step + 1e-9)) + 1)
    theta = 2.0 * np.pi * np.arange(headings) / headings
    c, s = np.cos(theta)[:, None, None], np.sin(theta)[:, None, None]
    r = radii[None, None, :]
    lat = np.asarray(lateral, dtype=np.float64)[None, :, None]
    x = r * c - lat * s  # forward
    y = r * s + lat * c  # left
    row = np.floor((extent_forward - x) / cell_size).astype(np.int64)
    col = np.floor((extent_side - y) / cell_size).astype(np.int64)
    inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    return np.where(inside, row * cols + col, rows * cols).reshape(headings, -1)


class CandidateStrips(nn.Module):
    """``(B, C, rows, cols)`` map (height, known; the stopped-drive channel with ``hazard_radius``) and ``(B, 7)``
    goal vector -> ``(B, headings * D + pooled)``.

    Args:
        rows, cols, cell_size, extent_forward, extent_side: the ``elevation_map`` encoding's geometry.
        headings, distances: the discrete action space's candidates (``frame=rover``).
        lateral: offsets (m) of the strip's lines either side of the heading's (the track's width).
        step, reach: spacing of a line's points and how far out they go (m).
        hidden: width of the per-heading network; ``context``: channels of the convolution over headings.
        channels: the map's channels, each gathered along every strip.
    """

    def __init__(
        self,
        rows: int,
        cols: int,
        cell_size: float,
        extent_forward: float,
        extent_side: float,
        headings: int,
        distances: Sequence[float],
        lateral: Sequence[float] = (-0.25, 0.0, 0.25),
        step: float = 0.25,
        reach: float = 4.0,
        hidden: int = 64,
        context: int = 32,
        channels: int = 2,
    ) -> None:
        super().__init__()
        if not (step > 0 and reach >= step):
            raise ValueError(f"strips: expected 0 < step <= reach, got step={step}, reach={reach}")
        if channels < 1:
            raise ValueError(f"strips: expected a map with >= 1 channel, got {channels}")
        if headings < 2 or not distances:
            raise ValueError(f"strips: expected >= 2 headings and >= 1 distance, got {headings}, {list(distances)}")
        index = strip_indices(rows, cols, cell_size, extent_forward, extent_side, headings, lateral, step, reach)
        self.register_buffer("index", torch.as_tensor(index, dtype=torch.long))
        theta = 2.0 * np.pi * np.arange(headings) / headings
        self.register_buffer("cos_theta", torch.as_tensor(np.cos(theta), dtype=torch.float32))
        self.register_buffer("sin_theta", torch.as_tensor(np.sin(theta), dtype=torch.float32))
        self.headings, self.n_distances = headings, len(distances)
        n_points = index.shape[1]
        self.per_heading = nn.Sequential(
            nn.Linear(channels * n_points + 5, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU()
        )
        self.context = nn.Sequential(
            nn.Conv1d(hidden, context, kernel_size=3, padding=1, padding_mode="circular"), nn.ReLU()
        )
        self.score = nn.Conv1d(hidden + context, self.n_distances, kernel_size=1)
        self.n_logits = headings * self.n_distances
        self.out_dim = self.n_logits + hidden + context

    def forward(self, grid: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        b, h = grid.shape[0], self.headings
        flat = torch.nn.functional.pad(grid.flatten(2), (0, 1))  # the last index: off the map (0, unknown)
        strips = flat[:, :, self.index]  # (B, C, H, P)
        strips = strips.permute(0, 2, 1, 3).reshape(b, h, -1)
        sin_e, cos_e = goal[:, 1:2], goal[:, 2:3]  # the goal's bearing from the rover's heading
        toward = self.cos_theta * cos_e + self.sin_theta * sin_e  # cos(heading - goal bearing), (B, H)
        across = self.sin_theta * cos_e - self.cos_theta * sin_e
        rest = goal[:, None, [0, 3, 4]].expand(b, h, 3)  # distance, roll, pitch
        x = torch.cat([strips, toward.unsqueeze(-1), across.unsqueeze(-1), rest], dim=-1)
        feats = self.per_heading(x).transpose(1, 2)  # (B, hidden, H)
        both = torch.cat([feats, self.context(feats)], dim=1)
        logits = self.score(both).transpose(1, 2).reshape(b, self.n_logits)  # heading-major
        return torch.cat([logits, both.mean(dim=2)], dim=1)


def init_logit_head(action_net: nn.Linear, offset: int, n: int) -> None:
    """Start a categorical head reading :class:`CandidateStrips` features (at ``offset`` of its input) as the
    identity on the candidates' logits and nothing else."""
    if action_net.out_features != n or action_net.in_features < offset + n:
        raise ValueError(
            f"init_logit_head: a head {action_net.in_features} -> {action_net.out_features} cannot read {n} logits "
            f"at offset {offset}"
        )
    with torch.no_grad():
        action_net.weight.zero_()
        action_net.bias.zero_()
        action_net.weight[:, offset : offset + n] = torch.eye(n)
