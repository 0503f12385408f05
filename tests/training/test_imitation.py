"""Imitation of the A* oracle (``train.imitation``): expert labels, DAgger, and the runner's imitation stage."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from diana_lab.agents.factory import build_model
from diana_lab.config import ConfigError, compose, validate
from diana_lab.config.run import ImitationConfig
from diana_lab.tracking import Tracker
from diana_lab.training.envs import env_config, make_env
from diana_lab.training.imitation import (
    CANDIDATES_KEY,
    LABEL_KEY,
    ExpertLabels,
    imitate,
    make_expert,
    soft_targets,
)
from tests.presets import CAMERA_SQUARE

from .helpers import ALGO_TINY, TINY, run_in_process, runs, store_args

FLAT = [*CAMERA_SQUARE, "world=flat", "sensor.width=16", "sensor.height=12"]
FLAT += ["episode.max_steps=20"]


def _groups(extra: list[str] | None = None) -> dict:
    return env_config(compose([*FLAT, *(extra or [])]))


@pytest.mark.parametrize("expert", ["astar", "astar_memory"])
def test_labels_are_the_oracles_action_and_can_be_switched_off(expert):
    env = make_env(_groups(), expert=ImitationConfig(enabled=True, expert=expert, knowledge_radius=6.0))
    if expert == "astar_memory":  # the expert that knows only what lay near the rover, and remembers it
        assert env.expert.knowledge_radius == 6.0 and env.expert.knowledge_memory
    assert isinstance(env, ExpertLabels)
    obs, info = env.reset(seed=3)
    label = info[LABEL_KEY]
    assert label.shape == (2,) and np.all(np.abs(label) <= 1.0)
    # on open flat ground the oracle heads straight for the goal: the label points along the goal bearing
    base = env.unwrapped
    offset = base.mapping.offset(label, base.pose_estimate.yaw)
    to_goal = base.goal - base.pose_estimate.xy
    cos = offset @ to_goal / (np.linalg.norm(offset) * np.linalg.norm(to_goal))
    assert cos > 0.99
    _, _, terminated, truncated, info = env.step(label)
    assert (LABEL_KEY in info) != (terminated or truncated)
    env.set_labelling(False)
    _, info = env.reset(seed=4)
    assert LABEL_KEY not in info
    env.close()


def _imitate(seed: int, steps: int, epochs: int, extra: list[str] | None = None, **imitation):
    """A small PPO policy on flat ground after 3 DAgger iterations: ``(model, venv, cfg, result)``."""
    groups = _groups(extra)
    settings = {"iterations": 3, "learning_rate": 3e-3, **imitation}
    cfg = ImitationConfig(enabled=True, steps_per_iteration=steps, epochs=epochs, **settings)
    venv = VecNormalize(DummyVecEnv([lambda: make_env(groups, expert=cfg) for _ in range(2)]), norm_reward=False)
    venv.seed(seed)
    overrides = [*FLAT, *(extra or []), "algo=ppo", "algo.net_arch=[32]", "algo.extractor.cnn_channels=[4]"]
    algo = validate(compose(overrides), ["algo"])
    model = build_model(algo["algo"], venv, seed=seed)
    return model, venv, cfg, imitate(model, venv, cfg, seed=seed, tracker=Tracker())


def test_dagger_fits_the_expert_and_sets_the_exploration_noise(monkeypatch):
    used = []
    real = torch.set_num_threads
    monkeypatch.setattr(torch, "set_num_threads", lambda n: (used.append(n), real(n)))
    before = torch.get_num_threads()
    model, venv, cfg, result = _imitate(seed=0, steps=256, epochs=8, fit_threads=2)
    assert used == [2, before] * 3  # every fit with fit_threads, then back to what the RL stage runs with
    assert torch.get_num_threads() == before
    assert result.steps == 3 * 256
    assert [row["beta"] for row in result.history] == [1.0, 0.5, 0.25]
    assert result.history[0]["learner_fraction"] == 0.0 and result.history[-1]["learner_fraction"] > 0.5
    assert result.history[-1]["loss"] < 0.5 * result.history[0]["loss"]
    assert torch.allclose(model.policy.log_std, torch.full_like(model.policy.log_std, cfg.log_std))
    # labelling is off for the RL stage that follows
    venv.reset()
    _, _, _, infos = venv.step(np.zeros((2, 2), dtype=np.float32))
    assert all(LABEL_KEY not in info for info in infos)
    venv.close()


def test_discrete_labels_are_the_candidates_nearest_to_the_experts_waypoints():
    env = make_env(_groups(["action_space=discrete"]), expert=ImitationConfig(enabled=True))
    base = env.unwrapped
    _, info = env.reset(seed=3)
    for _ in range(5):
        label = info[LABEL_KEY]
        assert label.dtype == np.int64 and label.shape == () and env.action_space.contains(label)
        est = base.pose_estimate
        target = env.expert._sent - est.xy  # the oracle's waypoint, shortened to the farthest candidate
        target *= min(1.0, base.mapping.extent / np.linalg.norm(target))
        c, s = np.cos(est.yaw), np.sin(est.yaw)
        candidates = base.mapping.candidates @ np.array([[c, s], [-s, c]])  # into the world frame
        gaps = np.linalg.norm(candidates - target, axis=1)
        assert gaps[label] == pytest.approx(gaps.min(), abs=1e-6)
        # on open flat ground the oracle heads for the goal: the candidate lies within half a heading bin of it
        offset, to_goal = candidates[label], base.goal - est.xy
        assert offset @ to_goal / (np.linalg.norm(offset) * np.linalg.norm(to_goal)) > np.cos(np.pi / 16) - 1e-6
        _, _, terminated, truncated, info = env.step(label)
        if terminated or truncated:
            break
    env.close()


def test_behaviour_cloning_of_discrete_labels_fits_a_categorical_policy():
    """Cross-entropy on the logits: from the uniform policy's ln(48) to a policy that names the expert's
    candidate (heading and distance) far more often than chance, on states it was not trained on."""
    discrete = ["action_space=discrete"]
    model, venv, _, result = _imitate(seed=0, steps=256, epochs=20, extra=discrete, iterations=2, beta_decay=1.0)
    losses = [row["loss"] for row in result.history]
    assert losses[-1] < 0.5 * np.log(48) and losses[-1] < losses[0]
    env = make_env(_groups(discrete), expert=ImitationConfig(enabled=True))
    obs, info = env.reset(seed=123)
    exact = near = 0
    for _ in range(100):
        label = int(info[LABEL_KEY])
        pred, _ = model.predict(venv.normalize_obs({k: v[None] for k, v in obs.items()}), deterministic=True)
        exact += int(pred[0]) == label
        near += (int(pred[0]) // 3 - label // 3) % 16 in (0, 1, 15)  # the same heading, or the next one
        obs, _, terminated, truncated, info = env.step(label)
        if terminated or truncated:
            obs, info = env.reset()
    assert exact >= 25 and near >= 80  # chance: 2 and 19
    env.close()
    venv.close()


def test_soft_targets_share_the_label_among_near_ties_by_their_cost():
    inf = np.inf
    costs = np.array([[10.0, 10.0, 10.5, inf, 12.0], [inf, inf, inf, inf, inf], [3.0, 2.0, 1.0, 0.0, inf]])
    actions = np.array([0, 2, 3])
    p = soft_targets(costs, actions, temperature=0.5)
    assert p.shape == costs.shape and p.dtype == np.float32
    np.testing.assert_allclose(p.sum(axis=1), 1.0, rtol=1e-6)
    assert p[0, 0] == pytest.approx(p[0, 1]) and p[0, 0] / p[0, 2] == pytest.approx(np.e, rel=1e-5)
    assert p[0, 3] == 0.0 and p[2, 4] == 0.0  # no way, no share
    np.testing.assert_array_equal(p[1], [0, 0, 1, 0, 0])  # no plan: the expert's action alone
    assert list(np.argsort(-p[2]))[:4] == [3, 2, 1, 0]
    sharp = soft_targets(costs, actions, temperature=0.05)
    assert sharp[0, 2] < p[0, 2] and sharp[0, :2].sum() > 0.99  # colder: nearer the expert's one choice


def test_candidate_costs_travel_with_each_label_and_the_label_costs_the_least():
    cfg = ImitationConfig(enabled=True, label_temperature=0.25)
    env = make_env(_groups(["action_space=discrete"]), expert=cfg)
    assert env.candidate_costs
    _, info = env.reset(seed=3)
    for _ in range(5):
        costs, label = info[CANDIDATES_KEY], int(info[LABEL_KEY])
        assert costs.shape == (env.action_space.n,) and costs.dtype == np.float32
        assert np.isfinite(costs).sum() > env.action_space.n // 2  # open flat ground: most candidates have a way
        assert costs[label] == np.min(costs)
        _, _, terminated, truncated, info = env.step(label)
        if terminated or truncated:
            break
    env.close()
    with pytest.raises(ValueError, match=r"train\.imitation\.label_temperature"):
        make_env(_groups(), expert=cfg)  # a continuous action space has no candidates to share a label


def test_dagger_with_soft_labels_fits_the_experts_cost_ranking():
    """The fitted policy's probabilities follow the expert's candidate costs on states it was not trained on:
    its most probable candidate is far cheaper than chance, and the cross-entropy falls towards the labels'
    own entropy."""
    discrete = ["action_space=discrete"]
    model, venv, cfg, result = _imitate(
        seed=0, steps=256, epochs=20, extra=discrete, iterations=2, beta_decay=1.0, label_temperature=0.25
    )
    losses = [row["loss"] for row in result.history]
    assert losses[-1] < losses[0] < np.log(48)
    env = make_env(_groups(discrete), expert=cfg)
    obs, info = env.reset(seed=123)
    regret, chance = [], []
    for _ in range(60):
        costs = info[CANDIDATES_KEY].astype(np.float64)
        finite = np.isfinite(costs)
        pred, _ = model.predict(venv.normalize_obs({k: v[None] for k, v in obs.items()}), deterministic=True)
        regret.append(costs[int(pred[0])] - costs[finite].min() if finite[int(pred[0])] else 10.0)
        chance.append(np.mean(costs[finite] - costs[finite].min()))
        obs, _, terminated, truncated, info = env.step(int(info[LABEL_KEY]))
        if terminated or truncated:
            obs, info = env.reset()
    assert np.mean(regret) < 0.25 * np.mean(chance)
    env.close()
    venv.close()


def test_imitated_policy_drives_to_the_goal_on_flat_ground():
    from diana_lab.evaluation import SB3Policy, make_suite, run_suite, summarize

    model, venv, _, _ = _imitate(seed=1, steps=512, epochs=10)
    env = make_env(_groups())
    suite = make_suite(env, 10, 7, 4.0, 12.0)
    summary = summarize(run_suite(SB3Policy(model, venv), env, suite))
    assert summary["success_rate"] >= 0.9
    env.close()
    venv.close()


def test_runner_logs_the_imitation_stage(tmp_path, capsys):
    args = [
        "algo=ppo",
        *TINY,
        *ALGO_TINY["ppo"],
        "train.imitation.enabled=true",
        "train.imitation.iterations=2",
        "train.imitation.steps_per_iteration=64",
        *store_args(tmp_path),
    ]
    assert run_in_process(args) == 0
    err = capsys.readouterr().err
    assert "imitation 2/2: beta" in err and "cost loss" not in err  # printed only with the cost loss on (was nan)
    client, (run,) = runs(tmp_path)
    assert run.info.status == "FINISHED" and run.data.tags["imitation_steps"] == "128"
    loss = client.get_metric_history(run.info.run_id, "imitation/loss")
    assert sorted(m.step for m in loss) == [0, 1]
    # the evaluation right after imitation is logged at step 0, before any RL step
    assert 0 in {m.step for m in client.get_metric_history(run.info.run_id, "eval_success_rate")}


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("train.imitation.beta=1.5", "train.imitation.beta"),
        ("train.imitation.iterations=0", "train.imitation.iterations"),
        ("train.imitation.expert=human", "train.imitation.expert"),
        ("train.imitation.knowledge_radius=0", "train.imitation.knowledge_radius"),
        ("train.imitation.fit_threads=-1", "train.imitation.fit_threads"),
        ("train.imitation.label_temperature=-0.1", "train.imitation.label_temperature"),
    ],
)
def test_bad_imitation_config_names_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        validate(compose([override]), ["train"])


CTG = ["+experiment=reference_ctg", "algo.extractor.cost_to_go.iterations=20", "episode.max_steps=30"]


def test_cost_labels_are_the_experts_map_in_the_observations_frame():
    """``info["expert_cost"]``: per map cell, the least log cost over its quarter points of the map the expert
    planned on, laid out like the elevation map (row 0 ahead, column 0 left), and the expert's fill (the
    cheapest cost) beyond what it knows and beyond the world's edge."""
    import math

    env = make_env(env_config(compose(CTG)), expert=ImitationConfig(enabled=True, expert="astar_memory", cost_weight=1))
    try:
        obs, info = env.reset(seed=5, options={"yaw": 0.7})
        label = info["expert_cost"].astype(np.float64)
        assert label.shape == obs["elevation_map"].shape[1:] and info["expert_cost"].dtype == np.float16
        state = env.unwrapped.dynamics.state
        known = env.expert.known
        yaw = state.rpy[2]
        ahead, left = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
        cheapest = np.log(known.cost[np.isfinite(known.cost)].min())
        inside = 0
        for row in range(0, 60, 7):
            for col in range(0, 60, 5):
                x, y = 12.0 - (row + 0.5) * 0.4, 12.0 - (col + 0.5) * 0.4
                pts = [state.position[:2] + (x + a) * ahead + (y + b) * left for a in (-0.1, 0.1) for b in (-0.1, 0.1)]
                px, py = np.array(pts).T
                on_map = known.inside(*known.world_to_cell(px, py))
                expected = np.where(on_map, np.log(np.clip(known.cost_at(px, py), 1, 1e4)), cheapest).min()
                assert label[row, col] == pytest.approx(expected, abs=3e-3), (row, col)
                inside += on_map.all()
        assert 20 <= inside < 108  # the rover starts near enough the edge that both kinds are checked
        assert label[0, 0] == pytest.approx(cheapest, abs=2e-3)  # 16.7 m away: beyond the 12 m it knows
        assert label.max() > 2 * label[29, 29]  # and the Mars yard is not all cheap ground
    finally:
        env.close()


def _expert_states(groups: dict, expert: ImitationConfig, seed: int, n: int) -> tuple[torch.Tensor, np.ndarray]:
    """``n`` elevation maps the expert drove through, and its cost labels for them."""
    env = make_env(groups, expert=expert)
    obs, info = env.reset(seed=seed)
    maps, labels = [], []
    for _ in range(n):
        maps.append(obs["elevation_map"])
        labels.append(info["expert_cost"])
        obs, _, terminated, truncated, info = env.step(info["expert_action"])
        if terminated or truncated:
            obs, info = env.reset()
    env.close()
    return torch.as_tensor(np.stack(maps)), np.stack(labels).astype(np.float32)


def test_the_cost_map_labels_teach_the_cost_to_go_network():
    """After DAgger with ``cost_weight``, the cost CNN is closer to the expert's log costs on states of
    other episodes than it started."""
    from diana_lab.training.imitation import _cost_loss

    groups = env_config(compose(CTG))
    expert = ImitationConfig(enabled=True, expert="astar_memory", cost_weight=10.0)
    venv = DummyVecEnv([lambda: make_env(groups, expert=expert) for _ in range(2)])
    venv.seed(0)
    model = build_model(validate(compose(CTG), ["algo"])["algo"], venv, seed=0)
    net = model.policy.features_extractor.encoders["elevation_map"]
    maps, labels = _expert_states(groups, expert, seed=99, n=48)
    with torch.no_grad():
        before = float(_cost_loss(net, maps, labels))
    cfg = ImitationConfig(
        enabled=True,
        expert="astar_memory",
        cost_weight=10.0,
        steps_per_iteration=128,
        epochs=24,
        iterations=1,
        batch_size=32,
    )
    result = imitate(model, venv, cfg, seed=0, tracker=Tracker())
    venv.close()
    with torch.no_grad():
        after = float(_cost_loss(net, maps, labels))
    assert np.isfinite(result.history[0]["cost_loss"])
    assert after < 0.8 * before, (before, after)


def test_the_astar_seen_expert_needs_the_policys_map_before_any_run_starts(tmp_path):
    args = ["+experiment=reference", "train.imitation.expert=astar_seen", "sensor.elevation_map.memory=false"]
    assert run_in_process(args + store_args(tmp_path)) == 2
    assert runs(tmp_path)[1] == []  # refused before an MLflow run was opened
    labels = ImitationConfig(enabled=True, expert="astar_seen")
    assert make_expert(labels).name == "astar_seen"


def test_cost_labels_need_the_cost_to_go_encoder():
    groups = env_config(compose(["+experiment=reference", "episode.max_steps=30"]))
    venv = DummyVecEnv([lambda: make_env(groups, expert=ImitationConfig(enabled=True, cost_weight=1.0))])
    model = build_model(validate(compose(["+experiment=reference"]), ["algo"])["algo"], venv, seed=0)
    cfg = ImitationConfig(enabled=True, cost_weight=1.0, steps_per_iteration=8, iterations=1)
    with pytest.raises(ConfigError, match="elevation_encoder=cost_to_go"):
        imitate(model, venv, cfg, seed=0, tracker=Tracker())
    venv.close()


def test_an_off_policy_actor_says_the_log_std_is_not_applied(tmp_path, capsys):
    """SAC's actor has no state-independent log std: ``train.imitation.log_std`` used to be skipped silently."""
    args = [
        "algo=sac",
        *TINY,
        *ALGO_TINY["sac"],
        "train.total_timesteps=128",
        "train.imitation.enabled=true",
        "train.imitation.iterations=1",
        "train.imitation.steps_per_iteration=64",
        "tracking.enabled=false",
        f"hydra.run.dir={tmp_path}/run",
    ]
    assert run_in_process(args) == 0
    assert "train.imitation.log_std=-1.5 is not applied: SAC's policy has no state-independent log std" in (
        capsys.readouterr().err
    )
