"""``elevation_encoder: strips``: the strips lie where the candidates drive, the network is equivariant to
turning, and the factory builds a policy whose logits are the network's."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from diana_lab.agents.factory import build_model
from diana_lab.agents.strips import CandidateStrips, strip_indices
from diana_lab.config import ConfigError, compose, validate
from diana_lab.envs.batched import BatchedRoverEnv
from diana_lab.training.envs import env_config, shared_world

# an odd grid: the rover stands at the centre of its middle cell, so turning by 90 degrees maps cells onto cells
GEOMETRY = {"rows": 35, "cols": 35, "cell_size": 0.25, "extent_forward": 4.375, "extent_side": 4.375}


def test_a_strip_follows_its_heading_from_the_rover_outwards():
    idx = strip_indices(**GEOMETRY, headings=4, lateral=[0.0], step=1.0, reach=4.0)
    rows, cols = np.divmod(idx, GEOMETRY["cols"])
    # heading 0 is straight ahead: the map's centre column, rows up towards row 0 (the forward edge)
    assert (cols[0] == 17).all() and list(rows[0]) == [13, 9, 5, 1]
    # heading 1 (90 deg, counter-clockwise) is to the left: the centre row, columns towards column 0
    assert (rows[1] == 17).all() and list(cols[1]) == [13, 9, 5, 1]
    # heading 2 is behind: rows towards the back edge
    assert (cols[2] == 17).all() and list(rows[2]) == [21, 25, 29, 33]
    # points beyond the map index its padding cell
    far = strip_indices(**GEOMETRY, headings=4, lateral=[0.0], step=1.0, reach=6.0)
    assert far[0, -1] == GEOMETRY["rows"] * GEOMETRY["cols"]


def test_turning_the_map_by_one_heading_turns_the_logits_by_one_heading():
    """A map turned by 90 degrees (4 headings) with the goal turned with it: every candidate's logit moves to the
    candidate 90 degrees round, because every heading is scored by the same weights."""
    torch.manual_seed(0)
    net = CandidateStrips(**GEOMETRY, headings=4, distances=[1.0, 2.0], lateral=[-0.25, 0.0, 0.25])
    grid = torch.rand(1, 2, 35, 35)
    bearing = 0.3
    goal = torch.tensor([[0.4, np.sin(bearing), np.cos(bearing), 0.0, 0.0, 0.0, 1.0]], dtype=torch.float32)
    # turn the world by +90 deg: what lay ahead now lies to the left (forward rows -> left columns)
    turned = torch.rot90(grid, k=1, dims=(2, 3))
    goal_turned = goal.clone()
    goal_turned[0, 1], goal_turned[0, 2] = np.sin(bearing + np.pi / 2), np.cos(bearing + np.pi / 2)
    logits = net(grid, goal)[0, :8].reshape(4, 2)
    logits_turned = net(turned, goal_turned)[0, :8].reshape(4, 2)
    assert torch.allclose(logits_turned, torch.roll(logits, shifts=1, dims=0), atol=1e-5)


def _venv(extra: list[str]) -> BatchedRoverEnv:
    overrides = ["world=flat", "sensor=lidar3d", "sensor.horizontal_resolution_deg=10", "sensor.encoding=elevation_map",
                 "sensor.elevation_map.cell_size=0.5", "action_space=discrete", *extra]  # fmt: skip
    groups = env_config(compose(overrides))
    return BatchedRoverEnv(groups, 2, world_instances=[shared_world(groups["world"])]), overrides


def test_auto_picks_strips_for_a_discrete_rover_frame_and_the_policy_reads_its_logits():
    venv, overrides = _venv([])
    algo = validate(compose([*overrides, "algo.net_arch=[16]"]), ["algo"])["algo"]
    assert algo.extractor.elevation_encoder == "auto"
    model = build_model(algo, venv, seed=0)
    net = model.policy.features_extractor.encoders["elevation_map"]
    assert isinstance(net, CandidateStrips)
    venv.seed(0)
    obs = venv.reset()
    obs_t, _ = model.policy.obs_to_tensor(obs)
    features = model.policy.extract_features(obs_t)
    with torch.no_grad():
        logits = model.policy.get_distribution(obs_t).distribution.logits
        expected = torch.log_softmax(net(obs_t["elevation_map"], obs_t["goal"])[:, :48], dim=1)
    assert features.shape[1] == model.policy.features_extractor.features_dim
    assert torch.allclose(logits, expected, atol=1e-5)  # the head starts as the identity on the network's logits
    venv.close()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["action_space.frame=world", "algo.extractor.elevation_encoder=strips"], "frame=rover"),
        (["sensor.encoding=depth_image", "algo.extractor.elevation_encoder=strips"], "elevation_map"),
    ],
)
def test_strips_refuse_what_they_cannot_score(extra, message):
    venv, overrides = _venv(extra)
    algo = validate(compose([*overrides, "algo.net_arch=[16]"]), ["algo"])["algo"]
    with pytest.raises(ConfigError, match=message):
        build_model(algo, venv, seed=0)
    venv.close()


def test_auto_falls_back_to_the_cnn_elsewhere():
    venv, overrides = _venv(["action_space.frame=world"])
    algo = validate(compose([*overrides, "algo.net_arch=[16]", "algo.extractor.cnn_channels=[4]"]), ["algo"])["algo"]
    model = build_model(algo, venv, seed=0)
    assert not isinstance(model.policy.features_extractor.encoders["elevation_map"], CandidateStrips)
    venv.close()
