"""The checks that refuse a model trained for another env (diana_lab.evaluation.compatibility), on spaces and
configs alone; loading real models and refusing them is in test_loading.py."""

from types import SimpleNamespace

import numpy as np
import pytest
from gymnasium import spaces
from omegaconf import OmegaConf

from diana_lab.config import ConfigError, compose
from diana_lab.evaluation.compatibility import (
    check_action_space,
    check_observation_space,
    config_differences,
    recorded_overrides,
    rerun_advice,
    settings_note,
)


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


def loaded_policy(train_overrides, label="run/model.zip", model=True):
    return SimpleNamespace(
        label=label, model=object() if model else None, train_cfg=compose(train_overrides),
        train_overrides=train_overrides,
    )  # fmt: skip


def test_a_policy_trained_with_its_lidar_mounted_elsewhere_is_said_with_the_override_to_add():
    """Same shapes, so nothing refused it: a network trained with the lidar 0.6 m up ran on the 0.3 m default
    without a word (found evaluating a candidate of issue 48's study)."""
    loaded = loaded_policy(["sensor.mount_xyz=[0.0,0.0,0.6]"])
    note = settings_note(loaded, compose([]), [])
    assert note is not None
    assert "sensor.mount_xyz: training [0.0, 0.0, 0.6], here [0.0, 0.0, 0.3]" in note
    assert "Re-run with the training's overrides: 'sensor.mount_xyz=[0.0,0.0,0.6]'" in note
    as_trained = compose(["sensor.mount_xyz=[0.0,0.0,0.6]"])
    assert settings_note(loaded, as_trained, ["sensor.mount_xyz=[0.0,0.0,0.6]"]) is None


def test_other_drive_lengths_for_as_many_candidates_are_said():
    loaded = loaded_policy(["action_space.distances=[1.0,2.0,4.0]"])
    note = settings_note(loaded, compose([]))
    assert note is not None and "action_space.distances: training [1.0, 2.0, 4.0], here [1.0, 2.0, 3.0]" in note


def test_no_note_without_a_model_its_training_config_or_a_key_the_training_predates():
    assert settings_note(loaded_policy(["sensor.max_range=9.0"], model=False), compose([])) is None
    assert settings_note(SimpleNamespace(label="m", model=object(), train_cfg=None), compose([])) is None
    old = loaded_policy([])
    sensor = OmegaConf.to_container(old.train_cfg.sensor)
    del sensor["max_range"]  # a config saved before the key existed
    old.train_cfg = OmegaConf.create(
        {"sensor": sensor, "action_space": OmegaConf.to_container(old.train_cfg.action_space)}
    )
    assert settings_note(old, compose(["sensor.max_range=9.0"])) is None
    assert "sensor.max_range" in settings_note(loaded_policy([]), compose(["sensor.max_range=9.0"]))
    assert settings_note(loaded_policy([]), compose(["sensor.nthreads=2"])) is None  # speed, not what it sees


def test_the_shipped_policy_is_noted_without_run_advice():
    note = settings_note(loaded_policy([], label="pretrained"), compose(["sensor.max_range=9.0"]))
    assert note is not None and "sensor.max_range: training 7.0, here 9.0" in note and "Re-run" not in note
