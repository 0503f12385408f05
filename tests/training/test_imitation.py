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
from diana_lab.training.imitation import LABEL_KEY, ExpertLabels, imitate

from .helpers import ALGO_TINY, TINY, run_in_process, runs, store_args

FLAT = ["world=flat", "sensor.width=16", "sensor.height=12", "episode.max_steps=20"]


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


def _imitate(seed: int, steps: int, epochs: int):
    """A small PPO policy on flat ground after 3 DAgger iterations: ``(model, venv, cfg, result)``."""
    groups = _groups()
    venv = VecNormalize(
        DummyVecEnv([lambda: make_env(groups, expert=ImitationConfig(enabled=True)) for _ in range(2)]),
        norm_reward=False,
    )
    venv.seed(seed)
    algo = validate(compose([*FLAT, "algo=ppo", "algo.net_arch=[32]", "algo.extractor.cnn_channels=[4]"]), ["algo"])
    model = build_model(algo["algo"], venv, seed=seed)
    cfg = ImitationConfig(enabled=True, iterations=3, steps_per_iteration=steps, epochs=epochs, learning_rate=3e-3)
    return model, venv, cfg, imitate(model, venv, cfg, seed=seed, tracker=Tracker())


def test_dagger_fits_the_expert_and_sets_the_exploration_noise():
    model, venv, cfg, result = _imitate(seed=0, steps=256, epochs=8)
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


def test_imitated_policy_drives_to_the_goal_on_flat_ground():
    from diana_lab.evaluation import SB3Policy, make_suite, run_suite, summarize

    model, venv, _, _ = _imitate(seed=1, steps=512, epochs=10)
    env = make_env(_groups())
    suite = make_suite(env, 10, 7, 4.0, 12.0)
    summary = summarize(run_suite(SB3Policy(model, venv), env, suite))
    assert summary["success_rate"] >= 0.9
    env.close()
    venv.close()


def test_runner_logs_the_imitation_stage(tmp_path):
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
    ],
)
def test_bad_imitation_config_names_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        validate(compose([override]), ["train"])
