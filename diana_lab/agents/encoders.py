"""Torch encoders of one observation key each; :mod:`diana_lab.agents.extractors` puts them together.

They are sized for CPU training on small inputs: a few thousand to a few hundred thousand parameters, so a
policy update costs about as much as a few env steps rather than dominating them.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["ImageCNN", "PointNet", "mlp"]


def mlp(in_dim: int, hidden: Sequence[int]) -> nn.Sequential:
    """``Linear -> ReLU`` per entry of ``hidden``; the output width is ``hidden[-1]``."""
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, width), nn.ReLU()]
        in_dim = width
    return nn.Sequential(*layers)


class ImageCNN(nn.Module):
    """Channel-first image ``(B, C, H, W)`` -> ``(B, out_dim)``.

    Strided 3x3 convolutions (the first 5x5) halve the resolution per layer; an adaptive average pool to a
    fixed ``pool`` grid then makes the head independent of the image size, so the same network works on a
    16 x 12 test camera, the 64 x 48 default and the paper's 112 x 112 (which would otherwise need a
    6 000-input linear layer).
    """

    def __init__(self, in_channels: int, channels: Sequence[int], out_dim: int, pool: tuple[int, int] = (3, 4)) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        c_in = in_channels
        for i, c_out in enumerate(channels):
            k = 5 if i == 0 else 3
            layers += [nn.Conv2d(c_in, c_out, kernel_size=k, stride=2, padding=k // 2), nn.ReLU()]
            c_in = c_out
        layers += [nn.AdaptiveAvgPool2d(tuple(pool)), nn.Flatten()]
        self.conv = nn.Sequential(*layers)
        self.head = nn.Sequential(nn.Linear(c_in * pool[0] * pool[1], out_dim), nn.ReLU())
        self.out_dim = out_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.conv(x))


class PointNet(nn.Module):
    """Masked PointNet: a shared per-point MLP, then a max pool over the valid points only.

    Input ``(B, N, F)`` whose column ``mask_index`` is 1 for real points and 0 for padding (see
    :class:`diana_lab.sensing.encoders.PointsEncoder`); the remaining columns are the point features. Padding
    is excluded from the max by setting its features to -inf; a frame without any point yields zeros (not
    -inf), so an empty cloud is an ordinary input.
    """

    def __init__(self, n_features: int, hidden: Sequence[int], out_dim: int, mask_index: int | None = -1) -> None:
        super().__init__()
        self.mask_index = None if mask_index is None else mask_index % n_features
        in_dim = n_features - (0 if self.mask_index is None else 1)
        self.point_mlp = mlp(in_dim, hidden)
        self.head = nn.Sequential(nn.Linear(hidden[-1], out_dim), nn.ReLU())
        self.out_dim = out_dim

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        if self.mask_index is None:
            feats = self.point_mlp(points)
            return self.head(feats.max(dim=1).values)
        keep = [i for i in range(points.shape[-1]) if i != self.mask_index]
        valid = points[..., self.mask_index] > 0.5  # (B, N)
        feats = self.point_mlp(points[..., keep])  # (B, N, hidden)
        feats = feats.masked_fill(~valid.unsqueeze(-1), float("-inf"))
        pooled = feats.max(dim=1).values
        pooled = torch.where(torch.isfinite(pooled), pooled, torch.zeros_like(pooled))
        return self.head(pooled)
