"""The learnt cost map + shortest-path policy network: exact cost-to-go, the way round a wall, gradients, the
policy head's start, ONNX, and the config errors."""

import math

import numpy as np
import pytest
import torch
from scipy.sparse import lil_array
from scipy.sparse.csgraph import dijkstra

from diana_lab.agents.cost_to_go import UNREACHED, CostToGoNet, init_policy_head
from diana_lab.agents.factory import build_model, policy_kwargs
from diana_lab.config import ConfigError, compose, to_object
from diana_lab.envs.action_spaces import candidate_offsets

GEOMETRY = {"cell_size": 0.4, "extent_forward": 12.0, "extent_side": 12.0, "distance_scale": 50.0}
CANDIDATES = candidate_offsets(16, [1.0, 2.0, 3.0])


def net(**kwargs) -> CostToGoNet:
    return CostToGoNet(2, 60, 60, **{**GEOMETRY, "candidates": CANDIDATES, **kwargs})


def goal_vector(distance: float, bearing_deg: float) -> torch.Tensor:
    b = math.radians(bearing_deg)
    return torch.tensor([[distance / 50.0, math.sin(b), math.cos(b), 0, 0, 0, 1]], dtype=torch.float32)


def reference_cost_to_go(cost: np.ndarray, start: np.ndarray, step: float) -> np.ndarray:
    """Dijkstra on the same graph: a super-source linked to every cell at its starting value; a step from a
    cell to its 8-neighbour costs the step's length times the cell's own cost."""
    h, w = cost.shape
    n = h * w
    graph = lil_array((n + 1, n + 1))
    for y in range(h):
        for x in range(w):
            if np.isfinite(start[y, x]) and start[y, x] < UNREACHED:
                graph[n, y * w + x] = start[y, x] + 1e-12  # csgraph reads 0 as no edge
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    ny, nx = y + dy, x + dx
                    if (dy or dx) and 0 <= ny < h and 0 <= nx < w:
                        graph[ny * w + nx, y * w + x] = math.hypot(dy, dx) * step * cost[y, x]
    return dijkstra(graph.tocsr(), indices=n)[:n].reshape(h, w)


@pytest.mark.parametrize("goal", [(3.0, 20.0), (30.0, 135.0)])
def test_the_backup_is_the_exact_least_cost_to_the_goal(goal):
    """On random costs, enough rounds give Dijkstra's answer from the goal cell and the window's border."""
    ctg = net(pool=6, iterations=100)  # 10 x 10 planning cells of 2.4 m
    rng = np.random.default_rng(0)
    cost = rng.uniform(1.0, 20.0, (10, 10))
    g = goal_vector(*goal)
    got = ctg.cost_to_go(torch.tensor(cost, dtype=torch.float32)[None], g)[0].double().numpy()
    d = float(g[0, 0]) * 50.0
    gx, gy = d * float(g[0, 2]), d * float(g[0, 1])
    xs, ys = ctg.cell_x.view(-1).double().numpy(), ctg.cell_y.view(-1).double().numpy()
    straight = np.hypot(xs[:, None] - gx, ys[None, :] - gy)
    border = np.ones((10, 10), bool)
    border[1:-1, 1:-1] = False
    start = np.where(border | (straight <= 0.75 * ctg.step), straight, np.inf)
    np.testing.assert_allclose(got, reference_cost_to_go(cost, start, ctg.step), rtol=1e-5)


@pytest.mark.parametrize("gap_side", ["left", "right"])
def test_the_untrained_head_takes_the_cheapest_way_round_a_wall(gap_side):
    """With the cost CNN replaced by a known cost map (a costly wall 4 m ahead with a gap on one side), the
    initial head's arg-max candidate turns towards the gap; without the wall it heads straight on."""
    ctg = net(iterations=40)
    cost = torch.ones(1, 30, 30)
    cost[0, 9:11, :] = 100.0  # rows 9, 10: 4.0-5.6 m ahead
    cost[0, 9:11, slice(4, 8) if gap_side == "left" else slice(22, 26)] = 1.0
    head = torch.nn.Linear(ctg.out_dim, ctg.n)
    init_policy_head(head, 0, ctg.n)
    g = goal_vector(9.0, 0.0)

    def best(c: torch.Tensor) -> np.ndarray:
        ctg.log_cost = lambda _: torch.log(c)  # the CNN's answer, given
        with torch.no_grad():
            return CANDIDATES[int(head(ctg(torch.zeros(1, 2, 60, 60), g)).argmax())]

    x, y = best(cost)
    assert (y > 0.5) == (gap_side == "left") and abs(y) > 0.5  # sideways, to the gap's side (y: left)
    x, y = best(torch.ones(1, 30, 30))
    assert x == pytest.approx(3.0) and y == pytest.approx(0.0, abs=1e-9)  # the far candidate straight ahead


def test_only_the_last_rounds_and_the_segments_carry_gradients():
    ctg = net(iterations=40, grad_iterations=3)
    cost = torch.ones(1, 30, 30, requires_grad=True)
    value = ctg.cost_to_go(cost, goal_vector(30.0, 0.0))
    value[0, 15, 15].backward()  # a cell near the rover
    touched = torch.nonzero(cost.grad[0])
    assert len(touched) > 0
    assert (touched - torch.tensor([15, 15])).abs().max() <= 3  # within 3 rounds' reach of the cell
    full = net(iterations=40, grad_iterations=40)
    cost.grad = None
    full.cost_to_go(cost, goal_vector(30.0, 0.0))[0, 15, 15].backward()
    assert (torch.nonzero(cost.grad[0])[:, 0]).min() == 1  # all the way to the border (whose value is given)


def test_the_recipe_builds_a_categorical_policy_that_starts_at_the_soft_arg_min_and_exports(tmp_path):
    import onnxruntime as ort

    from diana_lab.training.envs import make_env

    cfg = compose(["+experiment=reference_ctg", "algo.extractor.cost_to_go.iterations=30"])
    from stable_baselines3.common.vec_env import DummyVecEnv

    from diana_lab.training.envs import env_config

    venv = DummyVecEnv([lambda: make_env(env_config(cfg))])
    try:
        model = build_model(to_object("algo", cfg.algo), venv, seed=0)
        policy = model.policy
        ctg = policy.features_extractor.encoders["elevation_map"]
        assert isinstance(ctg, CostToGoNet) and ctg.n == venv.action_space.n == 96
        assert policy.action_net.in_features == policy.features_extractor.features_dim  # no hidden layer
        obs = venv.reset()
        obs_t, _ = policy.obs_to_tensor(obs)
        with torch.no_grad():
            features = ctg(obs_t["elevation_map"], obs_t["goal"])
            logits = policy.get_distribution(obs_t).distribution.logits
        end, segment, progress = features[0].view(3, -1) / 0.1
        expected = -5.0 * (end + segment) + 0.5 * progress
        np.testing.assert_allclose(logits[0] - logits[0].max(), expected - expected.max(), atol=1e-3)
        path = tmp_path / "ctg.onnx"
        torch.onnx.export(
            ctg.eval(), (obs_t["elevation_map"], obs_t["goal"]), str(path), input_names=["map", "goal"], dynamo=False
        )
        got = ort.InferenceSession(str(path)).run(None, {"map": obs["elevation_map"], "goal": obs["goal"]})
        np.testing.assert_allclose(got[0], features.numpy(), atol=1e-4)
    finally:
        venv.close()


def test_recipe_geometry_comes_from_the_sensor_and_the_candidates_from_the_action_space():
    cfg = compose(["+experiment=reference_ctg"])
    candidates = candidate_offsets(cfg.action_space.headings, list(cfg.action_space.distances))
    kwargs = policy_kwargs(to_object("algo", cfg.algo), len(candidates), candidates)
    ctg = kwargs["features_extractor_kwargs"]["cost_to_go"]
    assert ctg["cell_size"] == cfg.sensor.elevation_map.cell_size
    assert ctg["distance_scale"] == cfg.episode.distance_scale
    np.testing.assert_allclose(ctg["candidates"], candidates)
    assert kwargs["net_arch"] == {"pi": [], "vf": list(cfg.algo.net_arch)}


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["+experiment=reference_ctg", "algo.extractor.cost_to_go.grad_iterations=50"], "grad_iterations"),
        (["+experiment=reference_ctg", "algo.extractor.cost_to_go.max_cost=1"], "cost_to_go.max_cost"),
        (["algo.extractor.elevation_encoder=cost_to_go"], "cost_to_go: elevation_encoder=cost_to_go needs cell_size"),
        (["algo.extractor.elevation_encoder=cost_to_go", "algo.normalize=true"], "the cost_to_go encoder places"),
    ],
)
def test_bad_cost_to_go_settings_name_the_key(overrides, message):
    with pytest.raises(ConfigError, match=message):
        policy_kwargs(to_object("algo", compose(overrides).algo), 96, CANDIDATES)


def test_cost_to_go_without_a_discrete_action_space_is_refused():
    cfg = compose(["+experiment=reference_ctg"])
    with pytest.raises(ConfigError, match="action_space=discrete"):
        policy_kwargs(to_object("algo", cfg.algo))
    with pytest.raises(ValueError, match="pool=7"):
        net(pool=7)
