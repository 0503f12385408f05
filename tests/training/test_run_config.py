"""The run's config groups: the keys other parts rely on, their checks, and the experiment presets."""

import pytest

from diana_lab.config import ConfigError, compose, to_object


def test_defaults_have_the_keys_others_rely_on():
    cfg = compose()
    for key in ("total_timesteps", "n_envs", "vec_env", "checkpoint_every", "resume"):
        assert key in cfg.train
    assert cfg.tracking.enabled is True and cfg.tracking.uri == "sqlite:///mlflow.db"
    assert cfg.tracking.experiment and "episodes" in cfg.eval and "every" in cfg.eval
    assert cfg.algo.name == "ppo" and cfg.algo._target_ == "stable_baselines3.PPO"
    assert isinstance(cfg.seed, int)


def test_paper_experiment():
    cfg = compose(["+experiment=paper"])
    assert cfg.robot.name == "jackal" and cfg.algo.name == "ppo" and cfg.reward.name == "paper"
    assert (cfg.sensor.name, cfg.sensor.width, cfg.sensor.height) == ("depth_camera_paper", 112, 112)
    assert cfg.action_space.shape == "square" and cfg.action_space.frame == "world"


def test_quick_experiment_and_command_line_precedence():
    cfg = compose(["+experiment=quick"])
    assert cfg.world.name == "flat" and cfg.train.total_timesteps <= 50_000
    assert compose(["+experiment=quick", "world=hills", "train.n_envs=2"]).world.name == "hills"


@pytest.mark.parametrize(
    ("group", "override", "key"),
    [
        ("train", "train.total_timesteps=0", "train.total_timesteps"),
        ("train", "train.checkpoint_every=-5", "train.checkpoint_every"),
        ("train", "train.resume=''", "train.resume"),
        ("tracking", "tracking.experiment=''", "tracking.experiment"),
        ("algo", "algo=sac algo.tau=2", "algo.tau"),
        ("algo", "algo=td3 algo.gradient_steps=0", "algo.gradient_steps"),
        ("algo", "algo=tqc algo.top_quantiles_to_drop_per_net=-1", "algo.top_quantiles_to_drop_per_net"),
    ],
)
def test_bad_values_name_their_key(group, override, key):
    with pytest.raises(ConfigError, match=key):
        to_object(group, compose(override.split())[group])
