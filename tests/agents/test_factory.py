"""Every ``algo=`` option builds its SB3 class with the YAML's hyperparameters and our policy."""

import numpy as np
import pytest
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

from diana_lab.agents.extractors import RoverExtractor
from diana_lab.agents.factory import build_model
from diana_lab.config import ConfigError, compose, to_object

from .fake_env import FakeRoverEnv


def optimizer(model):
    """PPO's one optimiser, or SAC's actor's (its critic's follows the same schedule)."""
    return model.actor.optimizer if hasattr(model, "actor") else model.policy.optimizer


class LogRate(BaseCallback):
    """The optimiser's learning rate at every rollout's start (after the last update set it)."""

    def __init__(self, rates: list[float]) -> None:
        super().__init__()
        self.rates = rates

    def _on_rollout_start(self) -> None:
        self.rates.append(optimizer(self.model).param_groups[0]["lr"])

    def _on_step(self) -> bool:
        return True


ALGOS = {"ppo": "PPO", "a2c": "A2C", "sac": "SAC", "td3": "TD3", "ddpg": "DDPG", "tqc": "TQC"}


def algo_cfg(name: str, *overrides: str):
    return to_object("algo", compose([f"algo={name}", *overrides]).algo)


@pytest.mark.parametrize("name", list(ALGOS))
def test_build_model_for_every_algo(name):
    cfg = algo_cfg(name, "algo.learning_rate=0.0005", "algo.net_arch=[16,8]")
    env = make_vec_env(lambda: FakeRoverEnv("points"), n_envs=1, seed=0)
    model = build_model(cfg, env, seed=3)
    assert type(model).__name__ == ALGOS[name]
    assert model.learning_rate == pytest.approx(5e-4)
    assert model.seed == 3
    extractors = [m for m in model.policy.modules() if isinstance(m, RoverExtractor)]
    assert extractors and set(extractors[0].encoders) == {"goal", "points"}
    widths = [m.out_features for m in model.policy.modules() if type(m).__name__ == "Linear"]
    assert 16 in widths and 8 in widths  # algo.net_arch reached the heads
    if name in ("td3", "ddpg"):
        assert model.action_noise is not None
    action, _ = model.predict(env.reset(), deterministic=True)
    assert action.shape == (1, 2) and np.all(np.abs(action) <= 1)


def test_yaml_hyperparameters_reach_the_constructor():
    env = make_vec_env(lambda: FakeRoverEnv(), n_envs=2, seed=0)
    model = build_model(algo_cfg("ppo", "algo.n_steps=32", "algo.batch_size=16", "algo.gamma=0.9"), env, seed=0)
    assert (model.n_steps, model.batch_size, model.gamma) == (32, 16, 0.9)
    tqc = build_model(algo_cfg("tqc", "algo.buffer_size=500"), env, seed=0)
    assert tqc.top_quantiles_to_drop_per_net == 2 and tqc.replay_buffer.buffer_size == 250  # per env
    assert tqc.policy.critic.n_quantiles == 25


def test_tiny_ppo_learns_on_fake_env():
    env = make_vec_env(lambda: FakeRoverEnv("depth_image"), n_envs=2, seed=0)
    model = build_model(algo_cfg("ppo", "algo.n_steps=16", "algo.batch_size=16", "algo.n_epochs=1"), env, seed=0)
    model.learn(64)
    assert model.num_timesteps == 64


@pytest.mark.parametrize("name", ["ppo", "sac"])
def test_learning_rate_end_anneals_the_rate_and_survives_a_save(name, tmp_path):
    tiny = ["algo.n_steps=8", "algo.batch_size=16", "algo.n_epochs=1"]
    if name == "sac":
        tiny = ["algo.learning_starts=0", "algo.batch_size=16", "algo.buffer_size=200"]
    env = make_vec_env(lambda: FakeRoverEnv("depth_image"), n_envs=2, seed=0)
    rates: list[float] = []
    model = build_model(algo_cfg(name, *tiny, "algo.learning_rate=0.001", "algo.learning_rate_end=0.0002"), env, seed=0)
    model.learn(32, callback=LogRate(rates))
    assert rates[0] == pytest.approx(1e-3) and rates[-1] < rates[0] and rates[-1] >= 2e-4
    assert model.lr_schedule(0.0) == pytest.approx(2e-4) and model.lr_schedule(0.5) == pytest.approx(6e-4)
    model.save(tmp_path / "m.zip")
    loaded = type(model).load(tmp_path / "m.zip", env=env)
    assert loaded.lr_schedule(0.5) == pytest.approx(6e-4)  # train.resume goes on down the same line
    constant = build_model(algo_cfg(name, *tiny, "algo.learning_rate=0.001"), env, seed=0)
    constant.learn(32)
    assert optimizer(constant).param_groups[0]["lr"] == pytest.approx(1e-3)


@pytest.mark.parametrize("name", ["ppo", "a2c"])
def test_on_policy_algos_build_a_categorical_policy_for_discrete_waypoints(name):
    env = make_vec_env(lambda: FakeRoverEnv("depth_image", candidates=48), n_envs=2, seed=0)
    tiny = [
        "algo.n_steps=16",
        "algo.net_arch=[16]",
        *(["algo.batch_size=32", "algo.n_epochs=1"] if name == "ppo" else []),
    ]
    model = build_model(algo_cfg(name, *tiny), env, seed=0)
    assert type(model.policy.action_dist).__name__ == "CategoricalDistribution"
    assert getattr(model.policy, "log_std", None) is None  # nothing Gaussian left for imitation to set
    action, _ = model.predict(env.reset(), deterministic=True)
    assert action.shape == (2,) and action.dtype == np.int64 and np.all((action >= 0) & (action < 48))
    model.learn(64)
    assert model.num_timesteps == 64


@pytest.mark.parametrize("name", ["sac", "td3", "ddpg", "tqc"])
def test_off_policy_algos_refuse_discrete_waypoints_naming_both_keys(name):
    env = make_vec_env(lambda: FakeRoverEnv("depth_image", candidates=48), n_envs=1, seed=0)
    with pytest.raises(ConfigError, match=rf"algo={name} with action_space\.shape=discrete.*algo=ppo or algo=a2c"):
        build_model(algo_cfg(name), env, seed=0)


def test_gaussian_policy_kwargs_are_refused_for_discrete_waypoints():
    env = make_vec_env(lambda: FakeRoverEnv("depth_image", candidates=48), n_envs=1, seed=0)
    with pytest.raises(ConfigError, match=r"algo\.policy_kwargs\.log_std_init.*discrete"):
        build_model(algo_cfg("ppo", "+algo.policy_kwargs.log_std_init=-1.0"), env, seed=0)
    box = make_vec_env(lambda: FakeRoverEnv("depth_image"), n_envs=1, seed=0)  # a Gaussian policy takes it
    model = build_model(algo_cfg("ppo", "+algo.policy_kwargs.log_std_init=-1.0"), box, seed=0)
    assert float(model.policy.log_std.detach()[0]) == -1.0


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("algo.learning_rate=-1", "algo.learning_rate"),
        ("algo.learning_rate_end=-0.0001", "algo.learning_rate_end"),
        ("algo.net_arch=[64,0]", "algo.net_arch[1]"),
        ("algo.extractor.elevation_encoder=gru", "algo.extractor.elevation_encoder"),
        ("algo.n_steps=0", "algo.n_steps"),
    ],
)
def test_bad_algo_values_name_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
        algo_cfg("ppo", override)
