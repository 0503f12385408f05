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
    LABEL_KEY,
    ExpertLabels,
    imitate,
    make_expert,
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
    assert "imitation 2/2: beta" in err
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
    ],
)
def test_bad_imitation_config_names_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        validate(compose([override]), ["train"])


def test_the_astar_seen_expert_needs_the_policys_map_before_any_run_starts(tmp_path):
    args = ["+experiment=reference", "train.imitation.expert=astar_seen", "sensor.elevation_map.memory=false"]
    assert run_in_process(args + store_args(tmp_path)) == 2
    assert runs(tmp_path)[1] == []  # refused before an MLflow run was opened
    labels = ImitationConfig(enabled=True, expert="astar_seen")
    assert make_expert(labels).name == "astar_seen"


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
