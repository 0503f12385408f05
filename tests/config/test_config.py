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
        (["action_space=discrete", "action_space.headings=1"], "action_space.headings"),
        (["action_space=discrete", "action_space.distances=[1.0,4.0]"], "action_space.distances[1]"),
        (["action_space=discrete", "action_space.distances=[]"], "action_space.distances"),
        (["action_space=discrete", "action_space.min_distance=0.5"], "action_space.min_distance"),
    ],
)
def test_impossible_values_name_the_key(overrides, key):
    cfg = compose(overrides)
    with pytest.raises(ConfigError, match=key.replace(".", r"\.").replace("[", r"\[")):
        validate(cfg)


def test_a_required_key_left_out_is_named_with_what_it_is():
    """``world=dem`` without ``world.size_x`` read "world: Structured config of type DemConfig has missing
    mandatory value: size_x"."""
    with pytest.raises(ConfigError) as err:
        validate(compose(["world=dem", "world.path=site.npy", "world.size_y=60"]), ["world"])
    assert str(err.value) == (
        "world.size_x: missing, and required for world=dem: the DEM's extent along x in metres "
        "(a .npy file has no georeferencing)"
    )
    with pytest.raises(ConfigError) as err:
        to_object("world", "dem")  # the sizes may come from a GeoTIFF's georeferencing: only the path is required
    message = str(err.value)
    assert message == (
        "world.path: missing, and required for world=dem: the elevation file (GeoTIFF/TIFF, 8/16-bit PNG or .npy)"
    )
    assert "Structured config" not in message
    with pytest.raises(ConfigError) as err:
        to_object("robot", {"name": "mine"})  # several missing: each named, in the schema's order
    message = str(err.value)
    assert message.startswith("robot.urdf: missing, and required for robot=mine")
    assert "; robot.wheel_radius: missing" in message and "; robot.mass: missing" in message


def test_discrete_action_space_composes_with_the_on_policy_algos_only():
    for algo in ("ppo", "a2c"):
        objects = validate(compose(["action_space=discrete", f"algo={algo}"]), [*GROUPS, "algo"])
        action = objects["action_space"]
        assert (action.shape, action.headings, action.distances, action.frame) == (
            "discrete",
            16,
            [1.0, 2.0, 3.0],
            "rover",
        )
    for algo in ("sac", "td3", "ddpg", "tqc"):
        cfg = compose(["action_space=discrete", f"algo={algo}"])
        with pytest.raises(ConfigError, match=rf"^algo={algo} with action_space\.shape=discrete"):
            validate(cfg, [*GROUPS, "algo"])
        validate(cfg, GROUPS)  # the env groups alone are fine: the pairing is what cannot work
    with pytest.raises(ConfigError, match=r"algo\.policy_kwargs\.log_std_init"):
        validate(compose(["action_space=discrete", "+algo.policy_kwargs.log_std_init=-2"]), ["action_space", "algo"])


@pytest.mark.parametrize(
    "overrides",
    [["world.size_xx=3"], ["world=flat", "world.size_x=big"], ["world=moon"], ["robot=rover9000"]],
)
def test_misspelt_keys_types_and_options_fail_at_composition(overrides):
    with pytest.raises(Exception) as err:
        compose(overrides)
    text = str(err.value)
    assert any(part in text for part in ("size_xx", "size_x", "moon", "rover9000"))


def test_flags_read_the_words_the_readme_lists_and_refuse_others():
    """README, Reliability: true/false, yes/no, y/n, on/off (any case) and integers; another word is Hydra's error."""
    words = {"true": True, "No": False, "y": True, "OFF": False, "on": True, "0": False, "2": True}
    for word, value in words.items():
        assert compose([f"eval.video={word}"]).eval.video is value, word
    with pytest.raises(Exception, match=r"eval\.video=maybe") as err:
        compose(["eval.video=maybe"])
    assert "not a valid bool" in str(err.value.__cause__)


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
