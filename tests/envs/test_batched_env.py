"""The batched env as a Stable-Baselines3 ``VecEnv``: its contract, its seeding, its refusals, its slow paths."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from stable_baselines3.common.vec_env import VecNormalize

from diana_lab import config as C
from diana_lab.core.validation import ConfigError
from diana_lab.envs import ActionError
from diana_lab.envs.batched import BatchedRoverEnv
from diana_lab.training.envs import env_config, shared_world
from tests.presets import CAMERA_SQUARE

SMALL = [*CAMERA_SQUARE, "world=flat", "sensor.width=16", "sensor.height=12"]


def make(overrides: list[str], n: int = 3, worlds: list[dict] | None = None) -> BatchedRoverEnv:
    groups = env_config(C.compose(overrides))
    worlds = worlds or [groups["world"]]
    return BatchedRoverEnv(groups, n, worlds, [shared_world(w) for w in worlds])


def rollout(env: BatchedRoverEnv, seed: int, steps: int) -> list[np.ndarray]:
    env.seed(seed)
    obs = env.reset()
    rng = np.random.default_rng(0)
    out = [obs["goal"].copy()]
    for _ in range(steps):
        obs, rewards, dones, _ = env.step(rng.uniform(-1, 1, (env.num_envs, 2)).astype(np.float32))
        out += [obs["goal"].copy(), obs[env.sensor_key].copy(), rewards.copy(), dones.copy()]
    return out


def test_same_seed_same_rollout_other_seed_another() -> None:
    env = make(SMALL)
    first, again, other = rollout(env, 5, 15), rollout(env, 5, 15), rollout(env, 6, 15)
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    assert not np.array_equal(first[0], other[0])


def test_observations_lie_in_the_space_and_episode_ends_carry_sb3_keys() -> None:
    env = make([*SMALL, "episode.max_steps=4"])
    env.seed(0)
    obs = env.reset()
    assert env.observation_space.contains({k: v[0] for k, v in obs.items()})
    ended = 0
    rng = np.random.default_rng(1)
    for _ in range(9):
        obs, rewards, dones, infos = env.step(rng.uniform(-1, 1, (3, 2)).astype(np.float32))
        assert rewards.dtype == np.float32 and dones.dtype == bool
        for i in range(3):
            assert env.observation_space.contains({k: v[i] for k, v in obs.items()})
            if dones[i]:
                ended += 1
                info = infos[i]
                assert {"outcome", "is_success", "episode", "terminal_observation", "TimeLimit.truncated"} <= set(info)
                assert set(info["episode"]) >= {"r", "l", "t"}
                assert env.observation_space.contains(info["terminal_observation"])
                if info["outcome"] == "timeout":
                    assert info["TimeLimit.truncated"] and info["episode"]["l"] == 4
            else:
                assert infos[i] == {}
    assert ended >= 3


def test_vec_normalize_wraps_it() -> None:
    env = VecNormalize(make(SMALL), norm_obs_keys=["goal"])
    env.seed(0)
    env.reset()
    for _ in range(3):
        obs, *_ = env.step(np.zeros((3, 2), dtype=np.float32))
    assert np.all(np.isfinite(obs["goal"]))


def test_rovers_split_across_worlds() -> None:
    groups = env_config(C.compose(SMALL))
    hills = env_config(C.compose(["world=hills"]))["world"]
    env = make(SMALL, n=4, worlds=[groups["world"], hills])
    assert env.world_of.tolist() == [0, 1, 0, 1]
    env.seed(0)
    env.reset()
    # rover 1 stands on the hills, rover 0 on flat ground (height 0 everywhere)
    assert env.state[0, 2] == pytest.approx(env.robot.base_height)
    assert abs(env.state[1, 2] - env.robot.base_height) > 1e-3


def test_each_world_prices_its_rovers_path_to_the_goal_on_its_own_map() -> None:
    """``path_progress`` with the rovers split across two worlds: each rover's field is built on its own world's
    cost map, and its term is the change of that field's distance, rover by rover."""
    term = "+reward.terms.way={fn: diana_lab.envs.rewards.path_progress, weight: 1.0, params: {}}"
    groups = env_config(C.compose([*SMALL, term]))
    craters = env_config(C.compose(["world=craters"]))["world"]
    env = make([*SMALL, term], n=4, worlds=[groups["world"], craters])
    env.seed(0)
    env.reset()
    for part in env.parts:
        gd = part.goal_distance
        for i in part.rows:
            want = gd.at(gd.field(env.goal[i]), *env.state[i, :2])
            assert env.path_to_goal[i] == pytest.approx(want)
    before = env.path_to_goal.copy()
    env.step(np.zeros((4, 2), dtype=np.float32))
    way = env.reward_names.index("way")
    np.testing.assert_allclose(env.last_reward_terms[:, way], before - env.path_to_goal)
    flat, rough = (part.goal_distance.cost for part in env.parts)
    assert flat.shape != rough.shape or flat.mean() < rough.mean()  # two maps, not one map twice


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        (["dynamics=physics"], "dynamics=physics"),
        (["sensor.backend=open3d"], "sensor.backend=open3d"),
    ],
)
def test_what_it_cannot_step_is_refused_by_name(overrides: list[str], key: str) -> None:
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        make([*SMALL, *overrides])


def test_bad_actions_raise_action_errors() -> None:
    env = make(SMALL)
    env.seed(0)
    env.reset()
    with pytest.raises(ActionError, match="finite"):
        env.step(np.array([[0.0, np.nan], [0, 0], [0, 0]], dtype=np.float32))
    discrete = make([*SMALL, "action_space=discrete"])
    discrete.seed(0)
    discrete.reset()
    with pytest.raises(ActionError, match="outside"):
        discrete.step(np.array([0, 1, 99]))
    with pytest.raises(ActionError, match="integer"):
        discrete.step(np.array([0.0, 1.0, 2.0]))


def test_a_users_reward_term_runs_rover_by_rover_with_one_warning() -> None:
    term = "+reward.terms.mine={fn: tests.envs.test_batched_env.speed_bonus, weight: 2.0, params: {per: 4.0}}"
    env = make([*SMALL, term])
    assert "reward.terms.mine" in env.slow_paths
    env.seed(0)
    env.reset()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(3):
            env.step(np.full((3, 2), 0.5, dtype=np.float32))
    slow = [w for w in caught if "reward.terms.mine" in str(w.message)]
    assert len(slow) == 1 and "slow path" in str(slow[0].message)
    mine = env.reward_names.index("mine")
    # the term saw each rover's own waypoint: 2 x path length / 4
    assert np.all(env.last_reward_terms[:, mine] == pytest.approx(2.0 * env.length / 4.0))


def speed_bonus(ctx, per: float = 1.0) -> float:
    """A user's own term (imported by its dotted path in the test above)."""
    return ctx.waypoint.path_length / per


def test_expert_labels_are_each_rovers_oracle_action_and_dagger_runs_on_them() -> None:
    """DAgger on the batched env: every rover's label is its own oracle's choice (the same as the scalar env's
    ExpertLabels gives for the same episode), and ``imitate`` fits a policy through it."""
    from diana_lab.agents.factory import build_model
    from diana_lab.config.run import ImitationConfig, TrainConfig
    from diana_lab.tracking import Tracker
    from diana_lab.training.envs import make_env, make_training_env
    from diana_lab.training.imitation import LABEL_KEY, imitate

    overrides = [*SMALL, "action_space=discrete", "episode.max_steps=10"]
    cfg = C.compose(overrides)
    expert = ImitationConfig(enabled=True, iterations=2, steps_per_iteration=64, epochs=2)
    venv = make_training_env(cfg, TrainConfig(n_envs=2, vec_env="batched"), 5, expert=expert)
    venv.reset()
    scalar = make_env(env_config(cfg), expert=expert)
    _, info = scalar.reset(seed=5)
    assert int(venv.reset_infos[0][LABEL_KEY]) == int(info[LABEL_KEY])
    obs, _, dones, infos = venv.step(np.array([int(info[LABEL_KEY]), 0]))
    _, _, terminated, truncated, info = scalar.step(info[LABEL_KEY])
    if not (dones[0] or terminated or truncated):
        assert int(infos[0][LABEL_KEY]) == int(info[LABEL_KEY])
    scalar.close()
    algo = C.validate(C.compose([*overrides, "algo.net_arch=[16]", "algo.extractor.cnn_channels=[4]"]), ["algo"])
    model = build_model(algo["algo"], venv, seed=0)
    result = imitate(model, venv, expert, seed=0, tracker=Tracker())
    assert result.steps == 2 * 64 and len(result.history) == 2
    _, _, _, infos = venv.step(np.zeros(2, dtype=np.int64))
    assert all(LABEL_KEY not in i for i in infos)  # labelling is off after imitation
    venv.close()
