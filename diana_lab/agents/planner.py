"""A value-iteration planning network over the elevation map (Tamar et al., "Value Iteration Networks", 2016).

Why it exists: a plain CNN regressing the next waypoint from the map does not generalise from the labels a
2-core budget can afford. Measured on 5,000 expert-labelled Mars-yard states (held-out 2,000): CNNs of
151k-1.37M parameters explain under a quarter of the waypoint variance, while fitting the training set ever
better. Finding a way round hazards to a goal is a planning problem; this module builds the planner's
structure into the network so that only its parts have to be learnt:

1. ``hazard``: two small convolutions read the height/known channels and pool them to a coarser grid;
2. ``reward``: a 1x1 convolution of those features plus a goal channel (a Gaussian bump at the goal's cell,
   or where the line to the goal leaves the window when the goal lies beyond it) gives a reward map;
3. ``iterations`` rounds of value iteration, each a 3x3 convolution to ``actions`` Q channels and a max
   over them: a learnt, differentiable Bellman backup that spreads the goal's value round the hazards;
4. the Q and V values of the cells around the rover are the features the policy and value heads read.

Everything is convolutions, max, exp and arithmetic, so it exports to ONNX and runs in the deployment
runtime like the CNN. The goal bump needs the map's geometry (cell size, extents) and the goal scaling, given
as constructor arguments (the ``reference`` recipe interpolates them from ``sensor.elevation_map`` and
``episode``).
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["ValueIterationNet"]


class ValueIterationNet(nn.Module):
    """``(elevation map (B, C, H, W), goal vector (B, >=3)) -> (B, out_dim)`` features.

    Args:
        in_channels, rows, cols: the map's shape (``C, H, W``).
        cell_size, extent_forward, extent_side: the map's geometry (m): row 0 lies ``extent_forward`` ahead
            of the rover, column 0 ``extent_side`` to its left.
        distance_scale: the goal vector's first entry is ``distance / distance_scale``; its next two are
            ``sin`` and ``cos`` of the goal's bearing from the map's x axis.
        pool: cells of the map per planning cell (per side).
        hidden: width of the hazard features.
        actions: Q channels per backup.
        iterations: value-iteration rounds (the reach of the plan, in planning cells).
        patch: half-width (planning cells) of the block around the rover whose values become features.
        out_dim: feature width.
    """

    def __init__(
        self,
        in_channels: int,
        rows: int,
        cols: int,
        cell_size: float,
        extent_forward: float,
        extent_side: float,
        distance_scale: float,
        pool: int = 3,
        hidden: int = 8,
        actions: int = 8,
        iterations: int = 20,
        patch: int = 2,
        out_dim: int = 128,
    ) -> None:
        super().__init__()
        for name, value in (("pool", pool), ("hidden", hidden), ("actions", actions), ("iterations", iterations)):
            if value < 1:
                raise ValueError(f"ValueIterationNet: {name} must be >= 1, got {value}")
        if rows % pool or cols % pool:
            raise ValueError(f"ValueIterationNet: the map ({rows} x {cols}) must divide into pool={pool} blocks")
        self.iterations = int(iterations)
        h, w = rows // pool, cols // pool
        step = cell_size * pool
        # the rover's planning cell (centre at x = 0, y = 0) and the block of cells read around it
        r0, c0 = extent_forward / step - 0.5, extent_side / step - 0.5
        top, left = round(r0 - patch + 0.5), round(c0 - patch + 0.5)
        size = 2 * patch if abs(r0 - round(r0)) > 0.25 else 2 * patch + 1
        if top < 0 or left < 0 or top + size > h or left + size > w:
            raise ValueError(f"ValueIterationNet: a patch of {patch} cells round the rover leaves the {h} x {w} grid")
        self.window = (top, left, size)
        self.scale = float(distance_scale)
        self.step = float(step)
        self.origin = (float(extent_forward), float(extent_side))
        # goal clipped to the window's inner edge (planning-cell centres)
        self.limits = (extent_forward - step / 2, rows * cell_size - extent_forward - step / 2, extent_side - step / 2)
        self.register_buffer("row_index", torch.arange(h, dtype=torch.float32).view(1, h, 1), persistent=False)
        self.register_buffer("col_index", torch.arange(w, dtype=torch.float32).view(1, 1, w), persistent=False)
        self.hazard = nn.Sequential(
            nn.Conv2d(in_channels, hidden, 3, padding=1),
            nn.ReLU(),
            nn.MaxPool2d(pool),
            nn.Conv2d(hidden, hidden, 3, padding=1),
            nn.ReLU(),
        )
        self.reward = nn.Conv2d(hidden + 1, 1, 1)
        self.q_reward = nn.Conv2d(1, actions, 3, padding=1)
        self.q_value = nn.Conv2d(1, actions, 3, padding=1, bias=False)
        self.head = nn.Sequential(nn.Linear((actions + 1) * size * size, out_dim), nn.ReLU())
        self.out_dim = out_dim

    def goal_map(self, goal: torch.Tensor) -> torch.Tensor:
        """``(B, 1, h, w)``: a unit bump at the goal's planning cell, or where the way to it leaves the grid."""
        d = goal[:, 0] * self.scale
        x, y = d * goal[:, 2], d * goal[:, 1]
        ahead, behind, side = self.limits
        lim_x = torch.where(x >= 0, torch.full_like(x, ahead), torch.full_like(x, behind))
        shrink = torch.clamp(torch.minimum(lim_x / (x.abs() + 1e-6), side / (y.abs() + 1e-6)), max=1.0)
        row = (self.origin[0] - x * shrink) / self.step - 0.5
        col = (self.origin[1] - y * shrink) / self.step - 0.5
        d2 = (self.row_index - row.view(-1, 1, 1)) ** 2 + (self.col_index - col.view(-1, 1, 1)) ** 2
        return torch.exp(-0.5 * d2).unsqueeze(1)

    def values(self, elevation: torch.Tensor, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(Q (B, actions, h, w), V (B, 1, h, w))`` after the value iteration (for the features and plots)."""
        features = self.hazard(elevation)
        reward = self.reward(torch.cat([features, self.goal_map(goal)], dim=1))
        q_reward = self.q_reward(reward)
        q = q_reward
        value = q.amax(dim=1, keepdim=True)
        for _ in range(self.iterations):
            q = q_reward + self.q_value(value)
            value = q.amax(dim=1, keepdim=True)
        return q, value

    def forward(self, elevation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        q, value = self.values(elevation, goal)
        top, left, size = self.window
        near = torch.cat([q, value], dim=1)[:, :, top : top + size, left : left + size]
        return self.head(near.flatten(1))
