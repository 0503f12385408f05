"""A learnt cost map and a fixed shortest-path backup: the policy network of the reference recipe.

Why (measured on the Mars yard; docs/reference_policy.md has the figures): a policy that reads
the map through a CNN, or through a value-iteration network whose Bellman backup is itself learnt (Tamar et
al., 2016; :mod:`diana_lab.agents.planner`), imitates the A* expert poorly -- 50-60 % success against the
expert's 95 % -- because both must learn *planning* from a few tens of thousands of labels. Planning is
not what needs learning: the expert's choices differ from a straight line only where the ground is costly,
and the shortest way round costly ground is a fixed computation. What a network must learn is what the
sensor cannot say directly: how costly each cell of the observed elevation map is to drive over. So, like
Neural A* (Yonetani et al., 2021) and the cost-map learners of field robotics:

1. ``cost``: a small CNN turns the elevation map (height and known-mask channels) into a per-cell
   traversal cost ``>= 1`` on a grid ``pool`` times coarser than the map (imitation can supervise it with the
   expert's own cost map, :meth:`CostToGoNet.log_cost`);
2. ``iterations`` rounds of an 8-connected Bellman-Ford backup (a cell's value becomes the least over its
   neighbours of theirs plus the step's length times the cell's own cost: three max-pools of ``-value``)
   spread the cost-to-go from the goal's cell -- and from the window's border, which starts at its
   straight-line distance to the goal (the expert too takes ground it does not know as the cheapest);
3. for each action candidate of the discrete action space, the features are the cost-to-go at its end
   (bilinear), the cost of the straight segment to it, and its progress along the goal's direction.

The SB3 policy reads logits from these features through one linear layer (no hidden layers,
:func:`init_policy_head` starts it at ``-beta * (cost-to-go + segment)``), so the policy is a soft arg-min
over the candidates that imitation and RL fine-tune, and everything is convolutions, pads, slices, mins and
matrix products: it exports to ONNX and runs in the deployment runtime like the CNN.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["CostToGoNet", "init_policy_head"]

UNREACHED = 1.0e4  # cost-to-go of a cell no backup has reached yet
FEATURE_SCALE = 0.1  # features are in units of 10 m (cost-weighted), a scale MLPs take well


def _bilinear_rows(points: np.ndarray, h: int, w: int) -> np.ndarray:
    """``(len(points), h * w)`` bilinear weights of fractional grid points ``(row, col)`` (clamped inside)."""
    out = np.zeros((len(points), h * w), dtype=np.float32)
    r = np.clip(points[:, 0], 0.0, h - 1.0)
    c = np.clip(points[:, 1], 0.0, w - 1.0)
    r0, c0 = np.minimum(np.floor(r).astype(int), h - 2), np.minimum(np.floor(c).astype(int), w - 2)
    fr, fc = r - r0, c - c0
    for dr, dc, wt in ((0, 0, (1 - fr) * (1 - fc)), (1, 0, fr * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 1, fr * fc)):
        np.add.at(out, (np.arange(len(points)), (r0 + dr) * w + (c0 + dc)), wt)
    return out


def _backup(value: torch.Tensor, straight: torch.Tensor, diagonal: torch.Tensor) -> torch.Tensor:
    """One 8-connected Bellman-Ford round on ``(B, h, w)`` values; ``straight``/``diagonal`` are the costs of a
    step out of each cell along and across the grid. Beyond the window lies ``UNREACHED`` (padding ``-value``
    with ``-UNREACHED`` before max-pooling it), so no way leads out of it and back."""
    neg = F.pad(-value, (1, 1, 1, 1), value=-UNREACHED).unsqueeze(1)
    across = torch.maximum(F.max_pool2d(neg[..., 1:-1, :], (1, 3), 1), F.max_pool2d(neg[..., 1:-1], (3, 1), 1))
    around = F.max_pool2d(neg, 3, 1)
    return torch.minimum(value, torch.minimum(straight - across.squeeze(1), diagonal - around.squeeze(1)))


class CostToGoNet(nn.Module):
    """``(elevation map (B, C, H, W), goal vector (B, >=3)) -> (B, 3 * n_candidates)`` features.

    Args:
        in_channels, rows, cols: the map's shape (``C, H, W``).
        cell_size, extent_forward, extent_side: the map's geometry (m): row 0 lies ``extent_forward`` ahead of
            the rover, column 0 ``extent_side`` to its left.
        distance_scale: the goal vector's first entry is ``distance / distance_scale``; its next two are the
            ``sin`` and ``cos`` of the goal's bearing in the rover frame.
        candidates: ``(n, 2)`` waypoint offsets (m, rover frame: x forward, y left), the action space's.
        pool: map cells per planning cell (per side).
        hidden: channels of the cost CNN's first layers (its last two have twice as many).
        iterations: Bellman-Ford rounds (a path's reach, in planning cells; the window's half-width and more).
        max_cost: the cost of a cell the network deems impassable (costs are clamped to ``[1, max_cost]``).
        grad_iterations: only the last rounds pass gradients to the costs (the rest are detached), so a
            candidate's cost-to-go teaches the cost of the cells within that many cells of its end. Training
            through all rounds costs 8x the time (measured: 0.84 s against 0.11 s for 6 of 40 rounds, batch 256,
            one thread) and the cost CNN is mainly taught by the expert's cost map anyway.
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
        candidates: np.ndarray,
        pool: int = 2,
        hidden: int = 16,
        iterations: int = 40,
        max_cost: float = 100.0,
        grad_iterations: int = 6,
    ) -> None:
        super().__init__()
        for name, value in (("pool", pool), ("hidden", hidden), ("iterations", iterations)):
            if int(value) != value or value < 1:
                raise ValueError(f"CostToGoNet: {name} must be an integer >= 1, got {value!r}")
        if not 0 <= grad_iterations <= iterations:
            raise ValueError(f"CostToGoNet: grad_iterations must be in [0, iterations], got {grad_iterations!r}")
        if rows % pool or cols % pool:
            raise ValueError(f"CostToGoNet: the map ({rows} x {cols}) must divide into pool={pool} blocks")
        if not max_cost > 1.0:
            raise ValueError(f"CostToGoNet: max_cost must exceed 1, got {max_cost!r}")
        cand = np.asarray(candidates, dtype=np.float64).reshape(-1, 2)
        if not len(cand):
            raise ValueError("CostToGoNet: needs at least one action candidate")
        h, w = rows // pool, cols // pool
        step = cell_size * pool
        self.grid, self.step, self.pool = (h, w), float(step), int(pool)
        self.iterations, self.grad_iterations = int(iterations), int(grad_iterations)
        self.scale, self.n = float(distance_scale), len(cand)
        self.log_max = math.log(max_cost)
        # planning-cell centres in the rover frame
        xs = extent_forward - (np.arange(h) + 0.5) * step
        ys = extent_side - (np.arange(w) + 0.5) * step
        self.register_buffer("cell_x", torch.tensor(xs, dtype=torch.float32).view(1, h, 1), persistent=False)
        self.register_buffer("cell_y", torch.tensor(ys, dtype=torch.float32).view(1, 1, w), persistent=False)
        border = np.ones((h, w), dtype=bool)
        border[1:-1, 1:-1] = False
        self.register_buffer("border", torch.tensor(border).view(1, h, w), persistent=False)

        def grid_point(xy: np.ndarray) -> np.ndarray:
            return np.stack([(extent_forward - xy[:, 0]) / step - 0.5, (extent_side - xy[:, 1]) / step - 0.5], -1)

        ends = _bilinear_rows(grid_point(cand), h, w)
        # the segment's cost: its length times the mean cost of points every quarter of a planning cell
        seg = np.zeros_like(ends)
        for k, (x, y) in enumerate(cand):
            length = math.hypot(x, y)
            m = max(2, math.ceil(4 * length / step))
            t = (np.arange(m) + 0.5) / m
            seg[k] = _bilinear_rows(grid_point(np.outer(t, [x, y])), h, w).sum(0) * (length / m)
        self.register_buffer("end_weights", torch.tensor(ends.T), persistent=False)  # (h*w, n)
        self.register_buffer("segment_weights", torch.tensor(seg.T), persistent=False)
        self.register_buffer("candidates", torch.tensor(cand, dtype=torch.float32).T.contiguous(), persistent=False)
        # the map's cells are 0.4 m on the recipe: one full-resolution layer reads slopes and steps, a strided one
        # brings it to the planning grid (cheaper than pooling after two full-resolution layers, and as good:
        # held-out error of the expert's log cost 1.12 against 1.04 in half the time, 3,000 Mars-yard states)
        self.cost = nn.Sequential(
            nn.Conv2d(in_channels, hidden, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(hidden, hidden, 3, stride=pool, padding=1),
            nn.ReLU(),
            nn.Conv2d(hidden, 2 * hidden, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(2 * hidden, 2 * hidden, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(2 * hidden, 1, 1),
        )
        self.out_dim = 3 * self.n

    def log_cost(self, elevation: torch.Tensor) -> torch.Tensor:
        """``(B, h, w)`` log of the traversal cost per planning cell, in ``[0, log(max_cost)]``."""
        z = self.cost(elevation).squeeze(1)
        return torch.clamp(F.softplus(z), max=self.log_max)

    def cost_to_go(self, cost: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """``(B, h, w)`` least cost (m x cost) from every planning cell to the goal, given ``cost`` ``(B, h, w)``."""
        d = goal[:, 0:1, None] * self.scale
        gx, gy = d * goal[:, 2:3, None], d * goal[:, 1:2, None]
        straight = torch.sqrt((self.cell_x - gx) ** 2 + (self.cell_y - gy) ** 2)
        source = self.border | (straight <= 0.75 * self.step)
        value = torch.where(source, straight, torch.full_like(straight, UNREACHED))
        straight, diagonal = cost * self.step, cost * (self.step * math.sqrt(2.0))
        early = self.iterations - self.grad_iterations
        if early:
            with torch.no_grad():  # see ``grad_iterations``
                s, d = straight.detach(), diagonal.detach()
                for _ in range(early):
                    value = _backup(value, s, d)
        for _ in range(self.grad_iterations):
            value = _backup(value, straight, diagonal)
        return value

    def forward(self, elevation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        return self.features(torch.exp(self.log_cost(elevation)), goal)

    def features(self, cost: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The candidates' features given a cost map ``(B, h, w)`` (the CNN's, or any other)."""
        value = self.cost_to_go(cost, goal)
        end = torch.clamp(value.flatten(1) @ self.end_weights, max=UNREACHED)
        segment = cost.flatten(1) @ self.segment_weights
        progress = goal[:, 2:3] * self.candidates[0:1] + goal[:, 1:2] * self.candidates[1:2]
        return torch.cat([end, segment, progress], 1) * FEATURE_SCALE


def init_policy_head(action_net: nn.Linear, offset: int, n: int, beta: float = 5.0, progress: float = 0.5) -> None:
    """Start a categorical head reading :class:`CostToGoNet` features (at ``offset`` of its input) at
    ``logit_k = -beta * (cost-to-go_k + segment_k) + progress * progress_k`` (per metre) and nothing else, so
    the untrained policy already takes the cheapest way round what its cost map holds."""
    if action_net.out_features != n or action_net.in_features < offset + 3 * n:
        raise ValueError(
            f"init_policy_head: a head {action_net.in_features} -> {action_net.out_features} cannot read "
            f"{n} candidates' features at offset {offset}"
        )
    with torch.no_grad():
        action_net.weight.zero_()
        action_net.bias.zero_()
        eye = torch.eye(n) / FEATURE_SCALE
        action_net.weight[:, offset : offset + n] = -beta * eye
        action_net.weight[:, offset + n : offset + 2 * n] = -beta * eye
        action_net.weight[:, offset + 2 * n : offset + 3 * n] = progress * eye
