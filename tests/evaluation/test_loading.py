import re
from pathlib import Path

import numpy as np
import pytest
from gymnasium import spaces

from diana_lab.cli import UserError
from diana_lab.config import ConfigError, compose, to_object
from diana_lab.evaluation import run_suite
from diana_lab.evaluation.loading import (
    POLICY_NAMES,
    check_action_space,
    check_observation_space,
    config_differences,
    load_policy,
    recorded_overrides,
    rerun_advice,
)
from diana_lab.evaluation.suite import EpisodeSpec


def goal_space():
    return spaces.Box(-1, 1, (7,), np.float32)


def test_observation_mismatch_names_the_key_and_shapes():
    trained = spaces.Dict({"goal": goal_space(), "depth_image": spaces.Box(0, 1, (1, 48, 64), np.float32)})
    other = spaces.Dict({"goal": goal_space(), "depth_image": spaces.Box(0, 1, (1, 112, 112), np.float32)})
    with pytest.raises(ConfigError, match=r"'depth_image' is \(1, 48, 64\) float32 for the policy but \(1, 112, 112\)"):
        check_observation_space(trained, other, "model.zip")
    lidar = spaces.Dict({"goal": goal_space(), "elevation_map": spaces.Box(-1, 1, (2, 40, 40), np.float32)})
    with pytest.raises(ConfigError, match=r"expects observation key 'depth_image'.*'elevation_map'"):
        check_observation_space(trained, lidar, "model.zip")
    # bounds may differ (the goal distance bound follows the world size): not a mismatch
    wider = spaces.Dict(
        {
            "goal": spaces.Box(-2, 2, (7,), np.float32),
            "depth_image": spaces.Box(0, 1, (1, 48, 64), np.float32),
        }
    )
    check_observation_space(trained, wider, "model.zip")


@pytest.mark.parametrize(
    ("model_space", "env_space", "expected"),
    [
        (spaces.Discrete(48), spaces.Discrete(192), "48 candidate waypoints.*192 candidate waypoints"),
        (spaces.Discrete(96), spaces.Box(-1, 1, (2,)), r"96 candidate waypoints.*continuous \(2,\)"),
        (spaces.Box(-1, 1, (2,)), spaces.Discrete(96), r"continuous \(2,\).*96 candidate"),
    ],
)
def test_action_mismatch_names_both_spaces_and_the_differing_keys(model_space, env_space, expected):
    with pytest.raises(ConfigError, match=expected) as info:
        check_action_space(model_space, env_space, "m.zip", ["action_space.headings: training 16, here 64"])
    assert "action_space.headings: training 16, here 64" in str(info.value)
    check_action_space(model_space, model_space, "m.zip")  # the same space passes
    check_action_space(spaces.Box(-1, 1, (2,)), spaces.Box(-2, 2, (2,)), "m.zip")  # bounds may differ


def test_config_differences_name_the_keys():
    a = compose(["sensor=depth_camera"])
    b = compose(["sensor=depth_camera_paper"])
    diffs = config_differences(a, b, groups=("sensor",))
    assert any(d.startswith("sensor.width: training 64, here 112") for d in diffs)


def test_a_saved_sb3_model_loads_runs_and_is_refused_on_other_observations(tmp_path, flat_env):
    from stable_baselines3 import PPO

    from tests.evaluation.conftest import small_env

    model = PPO(
        "MultiInputPolicy",
        flat_env,
        n_steps=8,
        batch_size=8,
        policy_kwargs={"net_arch": [8]},
        device="cpu",
        seed=0,
    )
    model.save(tmp_path / "model.zip")
    cfg = compose(["world=flat"])
    loaded = load_policy(str(tmp_path / "model.zip"), cfg, to_object("eval", cfg.eval))
    assert loaded.model is not None and loaded.policy.vecnormalize is None
    # the slope shield picks among candidates: a continuous policy behind it is refused, naming the key
    shielded = compose(["world=flat", "eval.shield.enabled=true"])
    with pytest.raises(UserError, match=r"eval\.shield\.enabled.*continuous"):
        load_policy(str(tmp_path / "model.zip"), shielded, to_object("eval", shielded.eval))
    check_observation_space(loaded.model.observation_space, flat_env.observation_space, loaded.label)
    spec = EpisodeSpec(np.array([-3.0, 0.0]), 0.0, np.array([3.0, 0.0]), seed=1)
    assert len(run_suite(loaded.policy, flat_env, [spec])) == 1
    other = small_env("sensor.width=32", "sensor.height=24")
    try:
        with pytest.raises(ConfigError, match=r"depth_image.*\(1, 48, 64\).*\(1, 24, 32\)"):
            check_observation_space(loaded.model.observation_space, other.observation_space, loaded.label)
    finally:
        other.close()


def test_pretrained_without_its_files_says_what_is_missing(tmp_path, monkeypatch):
    """An install without the package data (e.g. a source tree copied without ``assets/``) names the file."""
    import diana_lab.evaluation.loading as loading
    from diana_lab.cli import UserError

    monkeypatch.setattr(loading, "PRETRAINED_DIR", tmp_path)
    with pytest.raises(UserError, match="not shipped") as err:
        load_policy("pretrained", compose([]), to_object("eval", compose([]).eval))
    assert str(tmp_path / "model.zip") in str(err.value)


def test_a_checkpoint_loads_its_own_observation_statistics_and_a_normalised_run_without_them_is_refused(
    tmp_path, flat_env
):
    """``checkpoints/rl_model_<n>_steps.zip`` used to look for ``vecnormalize.pkl`` beside it, find none and run
    on raw observations without a word."""
    from omegaconf import OmegaConf
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from tests.evaluation.conftest import small_env

    model = PPO("MultiInputPolicy", flat_env, n_steps=8, batch_size=8, policy_kwargs={"net_arch": [8]}, seed=0)
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / ".hydra").mkdir()
    OmegaConf.save(compose(["world=flat", "algo.normalize=true"]), run / ".hydra" / "config.yaml")
    model.save(run / "checkpoints" / "rl_model_8_steps.zip")
    stats = VecNormalize(DummyVecEnv([small_env]), norm_obs_keys=["goal"])
    stats.obs_rms["goal"].mean[:] = 3.25  # recognisable
    stats.save(run / "checkpoints" / "rl_model_vecnormalize_8_steps.pkl")
    stats.venv.close()
    cfg = compose(["world=flat"])
    loaded = load_policy(str(run / "checkpoints" / "rl_model_8_steps.zip"), cfg, to_object("eval", cfg.eval))
    assert loaded.policy.vecnormalize is not None
    assert np.allclose(loaded.policy.vecnormalize.obs_rms["goal"].mean, 3.25)

    (run / "checkpoints" / "rl_model_vecnormalize_8_steps.pkl").unlink()
    with pytest.raises(UserError, match=r"algo\.normalize=true.*rl_model_vecnormalize_8_steps\.pkl"):
        load_policy(str(run / "checkpoints" / "rl_model_8_steps.zip"), cfg, to_object("eval", cfg.eval))


def test_a_run_id_in_a_store_that_does_not_exist_is_refused_without_creating_it(tmp_path):
    db = tmp_path / "mlflow.db"
    cfg = compose([f"tracking.uri=sqlite:///{db}"])
    with pytest.raises(UserError, match=r"policy=0123456789abcdef0123456789abcdef: .*tracking\.uri=.*has no store"):
        load_policy("0123456789abcdef0123456789abcdef", cfg, to_object("eval", cfg.eval))
    assert not db.exists()


def test_rerun_advice_names_the_trainings_env_overrides_the_command_line_lacks(tmp_path):
    """A run id or model path evaluated without the training's overrides (``+experiment=quick``) used to be
    refused naming only the config keys that differ; the message now ends with what to add."""
    trained = ["+experiment=quick", "sensor.width=16", "train.total_timesteps=256", "seed=3", "'algo.net_arch=[8]'"]
    advice = rerun_advice(trained, ["policy=abc", "eval.episodes=2"])
    assert advice == "Re-run with the training's overrides: +experiment=quick sensor.width=16"  # env keys only
    assert rerun_advice(trained, ["+experiment=quick"]).endswith("overrides: sensor.width=16")
    assert rerun_advice(["world.obstacles=[a.obj,b.obj]"]).endswith("'world.obstacles=[a.obj,b.obj]'")  # pastable
    # every one given already: the mismatch is the command line's own
    assert "drop the other overrides" in rerun_advice(["sensor.width=16"], ["sensor.width=16", "sensor.width=32"])
    assert "default env" in rerun_advice(["train.total_timesteps=256"], ["sensor.width=32"])
    assert "not recorded" in rerun_advice(None)

    hydra = tmp_path / ".hydra"
    hydra.mkdir()
    (hydra / "config.yaml").write_text("seed: 0\n")
    assert recorded_overrides(hydra / "config.yaml") is None  # Hydra's overrides.yaml not kept
    (hydra / "overrides.yaml").write_text("- +experiment=quick\n- sensor.width=16\n")
    assert recorded_overrides(hydra / "config.yaml") == ["+experiment=quick", "sensor.width=16"]
    assert recorded_overrides(None) is None


def test_the_readmes_list_of_policies_is_the_one_the_program_accepts_and_names():
    """The README's Commands table left out ``astar_memory`` and ``cost_to_go_bound``."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    listed = re.search(r"python -m diana_lab\.evaluate policy=<([^>]*)>", readme)
    assert listed is not None
    assert [n.strip() for n in listed.group(1).split(",")] == ["run id", "model path", "pretrained", *POLICY_NAMES]
    cfg = compose([])
    with pytest.raises(UserError, match="policy=astr: no such model file") as err:
        load_policy("astr", cfg, to_object("eval", cfg.eval))
    assert f"({', '.join(POLICY_NAMES)})" in str(err.value)
