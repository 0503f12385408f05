"""The features extractor: one encoder per observation key, correct widths, masking of padded points."""

import numpy as np
import pytest
import torch
from gymnasium import spaces

from diana_lab.agents.encoders import ImageCNN, PointNet
from diana_lab.agents.extractors import RoverExtractor
from diana_lab.config import ConfigError

from .fake_env import SENSOR_SPACES, FakeRoverEnv


def batch(space: spaces.Dict, n: int = 3) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(np.stack([s.sample() for _ in range(n)])) for k, s in space.spaces.items()}


@pytest.mark.parametrize("key", list(SENSOR_SPACES))
def test_extractor_encodes_each_sensor_key(key):
    space = FakeRoverEnv(key).observation_space
    ext = RoverExtractor(space, goal_hidden=[32], sensor_features=24, cnn_channels=[8, 8], point_hidden=[16, 32])
    assert set(ext.encoders) == {"goal", key}
    assert ext.features_dim == 32 + 24
    out = ext(batch(space))
    assert out.shape == (3, 56)
    assert torch.isfinite(out).all()
    out.sum().backward()  # gradients reach every encoder
    assert all(p.grad is not None for p in ext.parameters())


def test_elevation_map_mlp_encoder():
    space = FakeRoverEnv("elevation_map").observation_space
    ext = RoverExtractor(space, elevation_encoder="mlp", sensor_features=16)
    assert not isinstance(ext.encoders["elevation_map"], ImageCNN)
    assert ext(batch(space)).shape == (3, 64 + 16)


@pytest.mark.parametrize("hw", [(12, 16), (48, 64), (112, 112)])
def test_image_cnn_output_width_does_not_depend_on_resolution(hw):
    cnn = ImageCNN(1, [8, 16, 16], out_dim=40)
    assert cnn(torch.rand(2, 1, *hw)).shape == (2, 40)


def test_pointnet_ignores_padding_and_handles_empty_clouds():
    torch.manual_seed(0)
    net = PointNet(4, [16, 32], out_dim=8)
    pts = torch.zeros(1, 10, 4)
    pts[0, :4, :3] = torch.rand(4, 3) * 2 - 1
    pts[0, :4, 3] = 1.0
    garbage = pts.clone()
    garbage[0, 4:, :3] = 5.0  # padded rows (mask 0) must not matter, whatever they hold
    assert torch.allclose(net(pts), net(garbage))
    moved = pts.clone()
    moved[0, 0, :3] += 0.5  # a real point does matter
    assert not torch.allclose(net(pts), net(moved))
    empty = torch.zeros(2, 10, 4)
    assert torch.isfinite(net(empty)).all()


def test_pointnet_is_order_invariant():
    net = PointNet(4, [16], out_dim=8)
    pts = torch.cat([torch.rand(1, 6, 3), torch.ones(1, 6, 1)], dim=-1)
    assert torch.allclose(net(pts), net(pts[:, torch.randperm(6)]), atol=1e-6)


def test_unknown_observation_key_is_refused_by_name():
    space = spaces.Dict({"goal": spaces.Box(-1, 1, (7,)), "thermal": spaces.Box(0, 1, (1, 8, 8))})
    with pytest.raises(ConfigError, match="thermal"):
        RoverExtractor(space)
