"""One SB3 features extractor for every observation the env can produce, dispatching on the dict keys.

``goal`` goes through an MLP; the sensor key through the encoder made for it: a CNN for ``depth_image``, a CNN
(or an MLP, or the candidate-strips network of :mod:`diana_lab.agents.strips`, which also reads the goal) for
``elevation_map``, a masked PointNet for ``points``. The features are concatenated and fed to
the policy/value heads (``algo.net_arch``). Because it reads the keys of the observation space, one
``policy_kwargs`` works for every sensor: swapping ``sensor=`` never needs a policy change.
"""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from diana_lab.agents.encoders import ImageCNN, PointNet, mlp
from diana_lab.agents.strips import CandidateStrips
from diana_lab.core.validation import ConfigError

__all__ = ["SENSOR_KEYS", "RoverExtractor"]

SENSOR_KEYS = ("depth_image", "elevation_map", "points")


class RoverExtractor(BaseFeaturesExtractor):
    """Features of a ``Dict`` observation with a ``goal`` vector and at most one sensor key per name above.

    Args:
        observation_space: the env's ``Dict`` space.
        goal_hidden: widths of the goal MLP.
        cnn_channels, cnn_pool: the image CNN's convolution widths and pooled grid (rows, cols).
        sensor_features: output width of every sensor encoder.
        elevation_encoder: ``"cnn"``, ``"mlp"`` (flattened grid) or ``"strips"`` for ``elevation_map``.
        point_hidden: widths of PointNet's shared per-point MLP.
        strips: :class:`CandidateStrips` arguments besides the map's shape (``elevation_encoder="strips"``).
    """

    def __init__(
        self,
        observation_space: gym.spaces.Dict,
        goal_hidden: Sequence[int] = (64, 64),
        cnn_channels: Sequence[int] = (16, 32, 32),
        cnn_pool: Sequence[int] = (3, 4),
        sensor_features: int = 128,
        elevation_encoder: str = "cnn",
        point_hidden: Sequence[int] = (64, 128),
        strips: dict | None = None,
    ) -> None:
        if not isinstance(observation_space, gym.spaces.Dict):
            raise ConfigError(f"algo.extractor: expected a Dict observation space, got {observation_space}")
        encoders: dict[str, nn.Module] = {}
        dims: dict[str, int] = {}
        for key, space in observation_space.spaces.items():
            shape = space.shape
            if key == "goal":
                encoders[key] = mlp(int(np.prod(shape)), goal_hidden)
                dims[key] = goal_hidden[-1]
            elif key == "elevation_map" and elevation_encoder == "strips":
                if len(shape) != 3 or not strips:
                    raise ConfigError(
                        "algo.extractor: the strips encoder needs a (C, H, W) map and the map's geometry and the "
                        f"action candidates, got shape {shape} and strips={strips!r}"
                    )
                encoders[key] = CandidateStrips(shape[1], shape[2], **strips, channels=shape[0])
                dims[key] = encoders[key].out_dim
            elif key == "depth_image" or (key == "elevation_map" and elevation_encoder == "cnn"):
                if len(shape) != 3:
                    raise ConfigError(f"algo.extractor: '{key}' must be (C, H, W), got shape {shape}")
                encoders[key] = ImageCNN(shape[0], cnn_channels, sensor_features, (cnn_pool[0], cnn_pool[1]))
                dims[key] = sensor_features
            elif key == "elevation_map" and elevation_encoder == "mlp":
                encoders[key] = nn.Sequential(nn.Flatten(), mlp(int(np.prod(shape)), [256, sensor_features]))
                dims[key] = sensor_features
            elif key == "elevation_map":
                raise ConfigError(
                    f"algo.extractor.elevation_encoder: {elevation_encoder!r} is not an encoder of the map here "
                    "(auto is decided by diana_lab.agents.factory.build_model); expected cnn, mlp or strips"
                )
            elif key == "points":
                if len(shape) != 2:
                    raise ConfigError(f"algo.extractor: 'points' must be (N, F), got shape {shape}")
                encoders[key] = PointNet(shape[1], point_hidden, sensor_features, mask_index=-1)
                dims[key] = sensor_features
            else:
                raise ConfigError(
                    f"algo.extractor: no encoder for observation key {key!r}; expected 'goal' "
                    f"and one of {', '.join(SENSOR_KEYS)}"
                )
        super().__init__(observation_space, features_dim=sum(dims.values()))
        self.encoders = nn.ModuleDict(encoders)
        self.dims = dims

    def offset(self, key: str) -> int:
        """Where ``key``'s features start in the concatenated feature vector."""
        keys = list(self.dims)
        return sum(self.dims[k] for k in keys[: keys.index(key)])

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        parts = []
        for key, encoder in self.encoders.items():
            x = observations[key]
            if isinstance(encoder, CandidateStrips):
                parts.append(encoder(x, observations["goal"].flatten(1)))
            else:
                parts.append(encoder(x.flatten(1) if key == "goal" else x))
        return torch.cat(parts, dim=1)
