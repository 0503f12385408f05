"""The composed config: every option of every group works, and bad input fails early naming the key."""

import subprocess
import sys

import pytest
from omegaconf import OmegaConf

from diana_lab.config import CONF_DIR, ConfigError, compose, to_object, validate

GROUPS = ["world", "robot", "dynamics", "sensor", "action_space", "reward", "episode"]


@pytest.mark.parametrize("group", GROUPS)
def test_every_option_composes_and_validates(group):
    options = sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))
    assert options, f"conf/{group} has no options"
    for option in options:
        if group == "world" and option == "dem":
            continue  # needs the user's file; covered by tests/sim/test_worlds.py
        cfg = compose([f"{group}={option}"])
        obj = to_object(group, cfg[group])
        assert getattr(obj, "name", option) == option


@pytest.mark.parametrize("preset", sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml")))
def test_every_experiment_preset_composes_and_validates(preset):
    cfg = compose([f"+experiment={preset}"])
    objects = validate(cfg, [*GROUPS, "algo", "train"])
    assert set(GROUPS) <= set(objects)


def test_default_config_validates_every_group():
    objects = validate(compose())
    assert set(GROUPS) <= set(objects)


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        (["world=flat", "world.size_x=-3"], "world.size_x"),
        (["world=flat", "world.resolution=0"], "world.resolution"),
        (["world=hills", "world.max_slope_deg=30"], "world.max_slope_deg"),
        (["world=craters", "world.rock_size=[0.5,0.2]"], "world.rock_size"),
        (["robot.cruise_speed=-1"], "robot.cruise_speed"),
        (["robot.turn_speed=0"], "robot.turn_speed"),
        (["robot.tipover_deg=120"], "robot.tipover_deg"),
        (["dynamics.controller.position_tolerance=0"], "dynamics.controller.position_tolerance"),
        (["dynamics=physics", "dynamics.time_step=1.0"], "dynamics.time_step"),
        (["episode.min_distance=30", "episode.max_distance=8"], "episode.min_distance"),
        (["episode.max_steps=0"], "episode.max_steps"),
        (["action_space.size=0"], "action_space.size"),
    ],
)
def test_impossible_values_name_the_key(overrides, key):
    cfg = compose(overrides)
    with pytest.raises(ConfigError, match=key.replace(".", r"\.").replace("[", r"\[")):
        validate(cfg)


@pytest.mark.parametrize(
    "overrides",
    [["world.size_xx=3"], ["world=flat", "world.size_x=big"], ["world=moon"], ["robot=rover9000"]],
)
def test_misspelt_keys_types_and_options_fail_at_composition(overrides):
    with pytest.raises(Exception) as err:
        compose(overrides)
    text = str(err.value)
    assert any(part in text for part in ("size_xx", "size_x", "moon", "rover9000"))


def test_cfg_job_prints_the_composed_config():
    out = subprocess.run(
        [sys.executable, "-m", "diana_lab", "--cfg", "job", "world=flat"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    cfg = OmegaConf.create(out.stdout)
    assert cfg.world.name == "flat" and cfg.robot.name == "jackal"
    for group in GROUPS:
        assert group in cfg
