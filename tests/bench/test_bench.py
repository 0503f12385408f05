"""Smoke test of ``python -m diana_lab.bench``: a tiny subset in-process, checking the JSON's structure.

No timing assertions (figures depend on the machine and its load); only that the keys, their shape and
the bookkeeping (targets, machine, versions) are what benchmarks/README.md documents.
"""

import json

import numpy as np
import pytest

from diana_lab.benchmarks import run, suite
from diana_lab.benchmarks.core import MEASUREMENTS, BenchContext, all_keys, select
from diana_lab.cli import UserError
from diana_lab.config import ConfigError, compose
from tests import entrypoints

FIGURE_FIELDS = {"value", "unit", "p10", "p90", "n", "batch", "target", "met", "anchor", "note"}
TOP_LEVEL = {
    "schema",
    "command",
    "date",
    "mode",
    "repeats",
    "machine",
    "versions",
    "threads",
    "config",
    "anchors",
    "figures",
    "errors",
}
DOCUMENTED = {
    "sensor_ms", "sensor_ms_pybullet_raytest", "sensor_ms_pybullet_raytest_mesh", "sensor_speedup",
    "sensor_ms_tinyrenderer", "elevation_map_ms", "sensor_ms_112", "physics_realtime_factor",
    "physics_realtime_factor_husky", "physics_realtime_factor_rocker_bogie", "kinematic_waypoints_per_s",
    "env_steps_per_s_kinematic", "env_steps_per_s_physics", "vec_env_scaling_2", "batched_env_steps_per_s",
    "batched_env_speedup", "batched_env_steps_per_s_depth", "train_fps_ppo", "train_fps_speedup", "rss_mb_per_rover",
    "policy_latency_ms_p50", "policy_latency_ms_p99", "rss_mb_per_env", "expert_label_ms",
    "shield_detour_ms_p50", "shield_detour_ms_p99", "hazcam_decision_ms_p50", "hazcam_decision_ms_p99",
    "sitemap_decision_ms_p50", "sitemap_decision_ms_p99",
}  # fmt: skip


def test_subset_writes_the_documented_json(tmp_path):
    out = tmp_path / "bench.json"
    only = "only=[kinematic_waypoints_per_s,sensor_ms]"
    cfg = compose(["quick=true", "repeats=1", f"output={out}", only], config_name="bench")
    result = run(cfg, command="pytest")
    saved = json.loads(out.read_text())
    assert saved == json.loads(json.dumps(result))
    assert set(saved) >= TOP_LEVEL
    assert saved["mode"] == "quick" and saved["repeats"] == 1 and saved["errors"] == {}
    assert set(saved["machine"]) >= {"cores", "cpu_model", "load_avg_before", "load_avg_after"}
    assert set(saved["versions"]) >= {"numpy", "open3d", "pybullet", "torch", "stable_baselines3", "gymnasium"}
    assert saved["threads"]["torch"] == 1

    figures = saved["figures"]
    # the sensor measurement brings its side-by-side figures along; nothing else ran
    assert set(figures) == {
        "kinematic_waypoints_per_s",
        "sensor_ms",
        "sensor_ms_pybullet_raytest",
        "sensor_ms_pybullet_raytest_mesh",
        "sensor_speedup",
        "sensor_ms_tinyrenderer",
    }
    for key, fig in figures.items():
        assert set(fig) >= FIGURE_FIELDS, key
        assert fig["value"] > 0 and fig["n"] == 1 and fig["p10"] <= fig["value"] <= fig["p90"], key
    kin = figures["kinematic_waypoints_per_s"]
    assert kin["target"] == {"op": ">=", "value": 5000.0} and isinstance(kin["met"], bool)
    assert figures["sensor_ms"]["target"] == {"op": "<=", "value": 0.3}
    assert figures["sensor_speedup"]["target"] == {"op": ">=", "value": 30.0}
    assert figures["sensor_ms_tinyrenderer"]["target"] is None and figures["sensor_ms_tinyrenderer"]["met"] is None
    # open3d and PyBullet cast the same rays against the same surface
    assert figures["sensor_ms_pybullet_raytest_mesh"]["max_range_diff_m"] < 1e-3


def test_expert_label_figure_times_the_reference_recipes_expert(tmp_path):
    cfg = compose(["quick=true", "repeats=1", f"output={tmp_path / 'b.json'}", "only=[expert_label_ms]"], "bench")
    fig = run(cfg, command="pytest")["figures"]["expert_label_ms"]
    assert fig["value"] > 0 and fig["unit"] == "ms" and fig["batch"] == "30 labels"
    assert fig["note"].startswith("astar_seen on +experiment=reference")


def quick_pair(tmp_path, p50_key: str, p99_key: str) -> tuple[dict, dict]:
    """A quick one-repeat run of a p50 / p99 pair of figures: the two figures, and nothing else ran."""
    cfg = compose(["quick=true", "repeats=1", f"output={tmp_path / 'b.json'}", f"only=[{p50_key},{p99_key}]"], "bench")
    figures = run(cfg, command="pytest")["figures"]
    assert set(figures) == {p50_key, p99_key}
    return figures[p50_key], figures[p99_key]


def test_the_detour_figure_times_stalled_decisions_of_the_reference_shield(tmp_path):
    p50, p99 = quick_pair(tmp_path, "shield_detour_ms_p50", "shield_detour_ms_p99")
    assert 0 < p50["value"] <= p99["value"] and p50["unit"] == "ms" and p50["batch"] == "48 decisions"
    assert "detour driving" in p50["note"] and p50["target"] is None
    assert p50["detours_per_run"] >= 40  # most of the 48 stalled decisions found a way and drove it


def test_the_hazard_camera_figure_times_decisions_that_map_four_camera_frames(tmp_path):
    p50, p99 = quick_pair(tmp_path, "hazcam_decision_ms_p50", "hazcam_decision_ms_p99")
    assert 0 < p50["value"] <= p99["value"] and p50["batch"] == "32 decisions"
    assert "x 4 hazard-camera frames" in p50["note"] and p50["target"] is None
    assert p50["returns_per_decision"] > 10_000 and 0 < p50["map_for_shield_p50_ms"] < p50["value"]


def test_the_site_map_figure_times_the_same_decisions_with_the_worlds_site_map(tmp_path):
    p50, p99 = quick_pair(tmp_path, "sitemap_decision_ms_p50", "sitemap_decision_ms_p99")
    assert 0 < p50["value"] <= p99["value"] and p50["batch"] == "32 decisions"
    assert "+experiment=reference_sitemap" in p50["note"] and "site map" in p50["note"]
    assert p50["returns_per_decision"] > 10_000


def test_the_decision_figures_goals_lie_on_the_map(mars_yard):
    """The full run's site-map figure once timed goals 20 m ahead off the map's edge (the Navigator warned):
    searches the suite never asks for. The goal keeps its distance and turns to the nearest bearing on the map."""
    from diana_lab.benchmarks.deploy import DETOUR_GOAL_M, GOAL_MARGIN_M, goal_on_map

    terrain = mars_yard.terrain
    inside = np.array([0.0, 0.0])
    assert goal_on_map(terrain, inside, 0.3) == pytest.approx(DETOUR_GOAL_M * np.array([np.cos(0.3), np.sin(0.3)]))
    edge = np.array([terrain.size_x / 2 - 3.0, 0.0])  # facing the east edge, 3 m from it
    goal = goal_on_map(terrain, edge, 0.0)
    assert np.hypot(*(goal - edge)) == pytest.approx(DETOUR_GOAL_M)
    assert terrain.contains(goal[0], goal[1], GOAL_MARGIN_M) and goal[0] < terrain.size_x / 2 - GOAL_MARGIN_M
    turned = np.degrees(np.arctan2(goal[1] - edge[1], goal[0] - edge[0]))
    assert abs(turned) == pytest.approx(85.0)  # the first 5-degree step with 20 cos(a) <= 3 m - the 1 m margin
    rng = np.random.default_rng(0)
    for xy in rng.uniform(-terrain.size_x / 2 + 1, terrain.size_x / 2 - 1, size=(200, 2)):
        g = goal_on_map(terrain, xy, rng.uniform(-np.pi, np.pi))
        assert terrain.contains(g[0], g[1], GOAL_MARGIN_M)


def test_every_documented_key_is_registered_once():
    keys = all_keys()
    assert len(keys) == len(set(keys))
    assert set(keys) == DOCUMENTED
    assert [m.name for m in select(["sensor_speedup"])] == ["sensor_vs_pybullet"]
    assert len(select(None)) == len(MEASUREMENTS)


def test_unknown_figure_names_the_choices():
    with pytest.raises(ValueError, match="only: unknown figure"):
        select(["sensor_mss"])


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("repeats=0", "repeats: expected a positive integer, got 0"),  # was: silently the default, 7
        ("repeats=2.7", "repeats: expected a positive integer, got 2.7"),  # was: silently 2
        ("repeats=abc", "repeats: expected a positive integer, got 'abc'"),
        ("quick=no", "quick: expected true or false, got 'no'"),  # was: bool("no"), a quick run
        ("profile=maybe", "profile: expected true or false, got 'maybe'"),
        ("output={tmp}", "is a folder; expected a file path"),  # was: an error after every measurement
        ("profile_output={tmp}", "profile_output={tmp}: '{tmp}' is a folder"),
    ],
)
def test_bad_options_stop_before_the_first_measurement(tmp_path, monkeypatch, override, message):
    def measure(*_):
        raise AssertionError("a measurement ran before the options were checked")

    monkeypatch.setattr(suite, "_measure", measure)
    extra = ["profile=true"] if override.startswith("profile_output") else []
    cfg = compose(["only=[kinematic_waypoints_per_s]", override.format(tmp=tmp_path), *extra], config_name="bench")
    with pytest.raises((ConfigError, UserError)) as info:
        run(cfg, command="pytest")
    assert message.format(tmp=tmp_path) in str(info.value)


def test_bad_option_exits_2_naming_the_key(tmp_path, capsys):
    code = entrypoints.run_in_process("diana_lab.bench", ["only=[]", "repeats=abc", f"hydra.run.dir={tmp_path}"])
    assert code == 2
    err = capsys.readouterr().err
    assert "repeats: expected a positive integer, got 'abc'" in err and "Traceback" not in err


def test_repeats_default_by_mode_and_as_given():
    assert BenchContext(compose(["quick=true"], config_name="bench")).repeats == 3
    assert BenchContext(compose([], config_name="bench")).repeats == 7
    assert BenchContext(compose(["repeats=2"], config_name="bench")).repeats == 2


@pytest.mark.parametrize("key", ["env_steps_per_s_kinematic", "rss_mb_per_env"])
def test_the_single_env_figures_run_under_the_main_commands_defaults(tmp_path, key):
    # they pin the square action space their random actions fit, whatever the composed config's action space
    cfg = compose(["quick=true", "repeats=1", f"output={tmp_path / 'b.json'}", f"only=[{key}]"], config_name="bench")
    assert cfg.action_space.shape == "discrete"  # the main command's
    result = run(cfg, command="pytest")
    assert result["errors"] == {}
    assert result["figures"][key]["value"] > 0


def test_the_training_anchor_is_the_old_main_command_reward_included():
    """``train_fps_speedup``'s anchor stays the main command as it was before the batched env: its sensor and
    actions, no tilt guard, and the reward of the time, which paid 0.5 for a stall that today's does not."""
    from diana_lab.benchmarks.batched import ANCHOR

    ctx = BenchContext(compose([], config_name="bench"))
    today, anchor = ctx.env_groups(), ctx.env_groups(*ANCHOR)
    assert today["reward"]["terms"]["stall"]["weight"] == 0.0
    assert anchor["reward"]["terms"]["stall"]["weight"] == 0.5
    assert anchor["sensor"]["encoding"] == "depth_image" and anchor["action_space"]["shape"] == "square"
    assert anchor["robot"]["tilt_guard_deg"] is None
    assert {k: v for k, v in anchor["reward"]["terms"].items() if k != "stall"} == {
        k: v for k, v in today["reward"]["terms"].items() if k != "stall"
    }
