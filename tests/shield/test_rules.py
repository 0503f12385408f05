"""The shield's settings defined once, its rules a configured list, and the ``shield/`` config group."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from omegaconf import OmegaConf

from diana_lab.config import ConfigError, compose, to_object
from diana_lab.config.evaluation import ShieldConfig
from diana_lab.core.candidates import candidate_offsets
from diana_lab.core.shield_rules import DEFAULT_RULES, ShieldRules
from diana_lab.shield import RULES, ShieldSettings, SlopeShield, register_rule

ROBOT = to_object("robot", "jackal")
FLAT = np.column_stack([np.mgrid[-6:6:0.05, -6:6:0.05].reshape(2, -1).T + 0.025, np.zeros(240 * 240)])


def seen(**overrides) -> SlopeShield:
    s = SlopeShield(ShieldSettings.from_config(ShieldConfig(enabled=True, **overrides), ROBOT))
    s.observe(FLAT, np.zeros(2))
    return s


def test_the_config_and_the_settings_share_one_definition_of_every_key():
    rule_keys = {f.name for f in dataclasses.fields(ShieldRules)}
    config_keys = {f.name for f in dataclasses.fields(ShieldConfig)}
    settings_keys = {f.name for f in dataclasses.fields(ShieldSettings)}
    assert config_keys - rule_keys == {"enabled", "cameras"}  # what only the simulator's evaluation has
    assert settings_keys - rule_keys == {"half_base", "half_track", "footprint_radius"}  # the robot's geometry
    # a preset's every rule key reaches the settings, and a sidecar's dict gives the same settings back
    cfg = to_object("eval", compose(["shield=hazcams"]).eval).shield
    settings = ShieldSettings.from_config(cfg, ROBOT)
    assert all(getattr(settings, k) == getattr(cfg, k) for k in rule_keys)
    assert ShieldSettings.from_dict(dataclasses.asdict(settings)) == settings


def test_a_bad_rule_key_is_named_alike_in_the_config_and_in_a_sidecar():
    with pytest.raises(ConfigError, match=r"eval\.shield\.peak_rank: expected an integer in 0\.\.8"):
        ShieldConfig(peak_rank=9)
    node = dataclasses.asdict(ShieldSettings.from_config(ShieldConfig(), ROBOT))
    with pytest.raises(ConfigError, match=r"shield\.peak_rank: expected an integer in 0\.\.8"):
        ShieldSettings.from_dict({**node, "peak_rank": 9})
    with pytest.raises(ConfigError, match=r"shield: unknown keys \['peak_rnak'\]"):
        ShieldSettings.from_dict({**node, "peak_rnak": 2})
    with pytest.raises(ConfigError, match=r"shield\.rules: expected each rule once"):
        ShieldSettings.from_dict({**node, "rules": ["route", "route"]})


def test_an_unknown_rule_is_refused_naming_the_key_and_the_rules_there_are():
    with pytest.raises(ConfigError, match=r"eval\.shield\.rules: unknown rules \['detuor'\]; expected names of"):
        ShieldSettings.from_config(ShieldConfig(rules=["approach", "detuor"]), ROBOT)
    with pytest.raises(ConfigError, match=r"eval\.shield\.rules: expected a list"):
        ShieldConfig(rules="approach")


def test_a_sidecar_written_before_the_rules_key_asks_the_rules_in_their_old_order():
    node = dataclasses.asdict(ShieldSettings.from_config(ShieldConfig(approach_radius=5.0), ROBOT))
    del node["rules"]
    assert ShieldSettings.from_dict(node).rules == list(DEFAULT_RULES)


def test_the_rules_decide_in_their_configured_order_and_a_rule_left_out_never_does():
    offsets = candidate_offsets(32, (1.0, 2.0, 3.0))
    goal = np.array([2.0, 0.0])  # 2 m ahead: the approach drives the 2 m candidate straight ahead
    ahead_2m = int(np.flatnonzero(np.all(np.isclose(offsets, [2.0, 0.0]), axis=1))[0])
    left = 8 * 3 + 2  # the policy wants 3 m to the left
    with_approach = seen(approach_radius=5.0, top_k=96)
    assert with_approach.choose([left, ahead_2m], offsets, np.zeros(2), goal) == ahead_2m
    assert with_approach.approaches == 1
    without = seen(approach_radius=5.0, top_k=96, rules=["detour", "route"])
    assert without.choose([left, ahead_2m], offsets, np.zeros(2), goal) == left  # the policy's own choice
    assert without.approaches == 0


def test_a_rule_of_your_own_is_a_registered_function_and_a_name_in_the_list():
    calls = []

    def last_candidate(shield, decision):
        calls.append(decision.offsets.shape)
        return len(decision.offsets) - 1

    register_rule("test_last_candidate")(last_candidate)
    try:
        with pytest.raises(ValueError, match="exists already"):
            register_rule("test_last_candidate")(last_candidate)
        offsets = candidate_offsets(32, (1.0, 2.0, 3.0))
        s = seen(top_k=3, approach_radius=5.0, rules=["test_last_candidate", "approach"])
        assert s.choose([5, 6, 7, 8], offsets, np.zeros(2), np.array([2.0, 0.0])) == 7  # the top_k's last
        assert calls == [(3, 2)] and s.approaches == 0  # asked before the approach, which never was
    finally:
        del RULES["test_last_candidate"]


@pytest.mark.parametrize("option", ["reference", "hazcams", "sitemap"])
def test_a_shield_option_is_what_its_experiment_preset_evaluates_behind(option):
    preset = {"reference": "reference", "hazcams": "reference_hazcams", "sitemap": "reference_sitemap"}[option]
    by_preset = compose([f"+experiment={preset}"]).eval.shield
    by_group = compose([f"shield={option}"]).eval.shield
    assert OmegaConf.to_container(by_group) == OmegaConf.to_container(by_preset)
    assert by_group.enabled
    assert compose([f"+experiment={preset}", "shield=off"]).eval.shield.enabled is False
    assert compose([]).eval.shield.enabled is False  # off by default


def test_an_unknown_shield_option_lists_the_options():
    from hydra.errors import MissingConfigException

    with pytest.raises(MissingConfigException, match="shield"):
        compose(["shield=refrence"])


def test_the_veto_only_option_checks_tilt_and_obstacles_and_never_steers(tmp_path):
    """``shield=veto``: the reference shield's checks on the rover's own map, none of its rules (approach, detour,
    route) and no memory of places or stopped drives; behind it the bearing baseline is vetoed on the yard and
    falls back to its next candidate, and no rule ever decides."""
    import json
    import subprocess
    import sys

    cfg = to_object("eval", compose(["shield=veto"]).eval).shield
    reference = to_object("eval", compose(["shield=reference"]).eval).shield
    assert cfg.enabled and list(cfg.rules) == [] and cfg.revisit_radius == 0 and cfg.hazard_radius == 0
    assert (cfg.limit_deg, cfg.obstacle_height) == (reference.limit_deg, reference.obstacle_height)
    assert list(ShieldSettings.from_config(cfg, ROBOT).rules) == []
    out = tmp_path / "summary.json"
    args = ["policy=bearing", "shield=veto", "eval.episodes=3", "eval.seed=1002", "eval.plots=false"]
    args += ["eval.video=false", "tracking.enabled=false", f"output={out}", f"hydra.run.dir={tmp_path / 'run'}"]
    proc = subprocess.run(
        [sys.executable, "-m", "diana_lab.evaluate", *args], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(out.read_text())
    assert summary["shield_veto_rate"] > 0
    assert summary["shield_approach_rate"] == summary["shield_detour_rate"] == summary["shield_route_rate"] == 0
    assert summary["shield_hazard_veto_rate"] == summary["shield_place_veto_rate"] == 0
