"""The value-iteration planning network: goal placement, planning round a wall, gradients, ONNX, config errors."""

import math

import numpy as np
import pytest
import torch

from diana_lab.agents.extractors import RoverExtractor
from diana_lab.agents.factory import policy_kwargs
from diana_lab.agents.planner import ValueIterationNet
from diana_lab.config import ConfigError, compose, to_object

from .fake_env import FakeRoverEnv

GEOMETRY = {"cell_size": 0.4, "extent_forward": 12.0, "extent_side": 12.0, "distance_scale": 50.0}


def net(**kwargs) -> ValueIterationNet:
    return ValueIterationNet(2, 60, 60, **{**GEOMETRY, **kwargs})


def goal_vector(distance: float, bearing_deg: float) -> torch.Tensor:
    b = math.radians(bearing_deg)
    return torch.tensor([[distance / 50.0, math.sin(b), math.cos(b), 0, 0, 0, 1]], dtype=torch.float32)


def bump_peak(vin: ValueIterationNet, distance: float, bearing_deg: float) -> tuple[float, float]:
    """The bump's centre (row, col) in planning cells, from its weighted mean."""
    g = vin.goal_map(goal_vector(distance, bearing_deg))[0, 0]
    rows, cols = torch.meshgrid(torch.arange(g.shape[0]), torch.arange(g.shape[1]), indexing="ij")
    w = g / g.sum()
    return float((w * rows).sum()), float((w * cols).sum())


def test_goal_bump_sits_at_the_goal_cell_and_on_the_border_beyond_the_window():
    vin = net()  # 20 x 20 planning cells of 1.2 m; the rover at (9.5, 9.5)
    r, c = bump_peak(vin, 3.0, 0.0)  # 3 m ahead: row (12 - 3) / 1.2 - 0.5 = 7
    assert r == pytest.approx(7.0, abs=0.05) and c == pytest.approx(9.5, abs=0.05)
    r, c = bump_peak(vin, 2.4, 90.0)  # 2.4 m to the left: column 9.5 - 2 = 7.5
    assert r == pytest.approx(9.5, abs=0.05) and c == pytest.approx(7.5, abs=0.05)
    g = vin.goal_map(goal_vector(30.0, 45.0))[0, 0]  # beyond the window, ahead-left: the corner cell
    assert np.unravel_index(int(g.argmax()), g.shape) == (0, 0)
    g = vin.goal_map(goal_vector(30.0, 180.0))[0, 0]  # far behind: the last row, centred
    assert int(g.argmax()) // 20 == 19


def handmade(vin: ValueIterationNet) -> ValueIterationNet:
    """Weights that make the network a textbook value iteration: reward = goal - 10 x height, 8 moves, gamma 0.9."""
    with torch.no_grad():
        for p in vin.parameters():
            p.zero_()
        vin.hazard[0].weight[0, 0, 1, 1] = 1.0  # feature 0 = the height channel, max-pooled
        vin.hazard[3].weight[0, 0, 1, 1] = 1.0
        vin.reward.weight[0, 0, 0, 0] = -10.0
        vin.reward.weight[0, -1, 0, 0] = 1.0  # the goal channel
        moves = [(u, v) for u in range(3) for v in range(3) if (u, v) != (1, 1)]
        for a, (u, v) in enumerate(moves):
            vin.q_reward.weight[a, 0, 1, 1] = 1.0
            vin.q_value.weight[a, 0, u, v] = 0.9  # Q_a(cell) = R(cell) + 0.9 V(cell + move_a)
    return vin


@pytest.mark.parametrize("gap_side", ["left", "right"])
def test_value_iteration_leads_round_a_wall_through_its_gap(gap_side):
    vin = handmade(net(iterations=30))
    wall = torch.zeros(1, 2, 60, 60)
    wall[0, 0, 15:18, :] = 1.0  # a wall across the map 5 m ahead (planning row 5)...
    gap = slice(6, 12) if gap_side == "left" else slice(48, 54)  # ...with a 2.4 m gap on one side
    wall[0, 0, 15:18, gap] = 0.0
    with torch.no_grad():
        q, v = vin.values(wall, goal_vector(9.0, 0.0))
        no_wall, _ = vin.values(torch.zeros(1, 2, 60, 60), goal_vector(9.0, 0.0))
    moves = [(u - 1, w - 1) for u in range(3) for w in range(3) if (u, w) != (1, 1)]
    best = moves[int(q[0, :, 10, 10].argmax())] if gap_side == "left" else moves[int(q[0, :, 10, 9].argmax())]
    assert best[1] == (-1 if gap_side == "left" else 1)  # first move: towards the gap's side, not straight on
    assert float(v[0, 0, 5, 10]) < float(v[0, 0, 7, 10])  # the wall is worth less than the ground before it
    assert moves[int(no_wall[0, :, 10, 10].argmax())][0] == -1  # without it: ahead


def test_extractor_with_the_planner_trains_and_exports_to_onnx(tmp_path):
    import onnxruntime as ort

    space = FakeRoverEnv("elevation_map").observation_space  # a 20 x 16 map
    planner = {"pool": 2, "iterations": 6, "patch": 1, **GEOMETRY, "extent_forward": 4.0, "extent_side": 3.2}
    ext = RoverExtractor(space, elevation_encoder="vin", sensor_features=16, goal_hidden=[8], planner=planner)
    assert isinstance(ext.encoders["elevation_map"], ValueIterationNet)
    obs = {k: torch.as_tensor(np.stack([s.sample() for _ in range(4)])) for k, s in space.spaces.items()}
    out = ext(obs)
    assert out.shape == (4, 24)
    out.sum().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in ext.parameters())
    path = tmp_path / "vin.onnx"
    vin = ext.encoders["elevation_map"].eval()
    torch.onnx.export(vin, (obs["elevation_map"], obs["goal"]), str(path), input_names=["map", "goal"], dynamo=False)
    got = ort.InferenceSession(str(path)).run(None, {"map": obs["elevation_map"].numpy(), "goal": obs["goal"].numpy()})
    with torch.no_grad():
        np.testing.assert_allclose(got[0], vin(obs["elevation_map"], obs["goal"]).numpy(), atol=1e-5)


def test_vin_recipe_builds_its_planner_from_the_sensor_geometry():
    cfg = compose(["+experiment=reference_vin"])
    kwargs = policy_kwargs(to_object("algo", cfg.algo))["features_extractor_kwargs"]
    assert kwargs["elevation_encoder"] == "vin"
    em = cfg.sensor.elevation_map
    assert kwargs["planner"]["cell_size"] == em.cell_size and kwargs["planner"]["extent_side"] == em.extent_side
    assert kwargs["planner"]["distance_scale"] == cfg.episode.distance_scale


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["algo.extractor.elevation_encoder=vin"], "algo.extractor.planner: elevation_encoder=vin needs cell_size"),
        (["+experiment=reference_vin", "algo.extractor.planner.iterations=0"], "algo.extractor.planner.iterations"),
        (["+experiment=reference_vin", "algo.extractor.planner.cell_size=-1"], "algo.extractor.planner.cell_size"),
        (["algo.extractor.elevation_encoder=vin", "algo.normalize=true"], "algo.normalize: the vin encoder"),
    ],
)
def test_bad_planner_settings_name_the_key(overrides, message):
    with pytest.raises(ConfigError, match=message):
        policy_kwargs(to_object("algo", compose(overrides).algo))


def test_planner_geometry_that_does_not_fit_the_map_is_refused():
    with pytest.raises(ValueError, match="pool=7"):
        net(pool=7)
    with pytest.raises(ValueError, match="patch of 12 cells"):
        net(patch=12)
