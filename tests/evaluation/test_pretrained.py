"""The shipped reference policy (``policy=pretrained``): its files, its recipe, its card, its results.

The fast tests check what could silently drift: the weights load and fit the env of the preset they were
trained with, the shipped training config is exactly what ``+experiment=reference`` composes today, and the
card's figures are well-formed. The slow ones re-run what the card claims: the 20-episode suite, and the
ONNX export's parity with torch on 1,000 recorded Mars-yard observations (issue 10).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from omegaconf import OmegaConf

from diana_lab.config import compose, to_object
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.evaluate import env_config
from diana_lab.evaluation.compatibility import check_observation_space
from diana_lab.evaluation.loading import PRETRAINED_DIR, load_policy
from diana_lab.shield import VETO_CHECKS

from .test_cli import evaluate_cli

CARD = PRETRAINED_DIR / "card.json"
RATES = ("success_rate", "spl", "collision_rate", "tipover_rate", "stuck_rate", "timeout_rate")


def card() -> dict:
    return json.loads(CARD.read_text())


def reference_cfg(*overrides: str):
    return compose(["+experiment=reference", "tracking.enabled=false", *overrides])


def test_the_shipped_files_are_there_and_small():
    for name in ("model.zip", "config.yaml", "card.json"):
        assert (PRETRAINED_DIR / name).is_file(), name
    assert (PRETRAINED_DIR / "model.zip").stat().st_size < 5e6  # "weights (small)"


def test_the_shipped_config_is_what_the_preset_composes_today():
    """Every key the policy was trained with has the value ``+experiment=reference`` gives it now (keys added
    to the code since then may only be new), so the preset reproduces the recipe and the evaluation builds
    the env the policy was trained in."""
    shipped = OmegaConf.load(PRETRAINED_DIR / "config.yaml")
    now = compose(["+experiment=reference"])
    assert OmegaConf.merge(now, shipped) == now
    assert card()["recipe"]["command"] == "python -m diana_lab +experiment=reference"


def test_it_loads_and_fits_the_preset_env():
    cfg = reference_cfg()
    loaded = load_policy("pretrained", cfg, to_object("eval", cfg.eval))
    env = RoverNavEnv(config=env_config(cfg, None, loaded.train_cfg))
    try:
        check_observation_space(loaded.model.observation_space, env.observation_space, "pretrained")
        obs, _ = env.reset(seed=0)
        loaded.policy.reset(env)
        action = loaded.policy.act(obs, env)
        assert env.action_space.contains(action)
    finally:
        env.close()


def test_without_the_preset_the_cli_says_which_preset_to_add(tmp_path):
    proc = evaluate_cli(tmp_path / "run", "policy=pretrained", "eval.episodes=1", "tracking.enabled=false")
    assert proc.returncode == 2
    assert "+experiment=reference" in proc.stderr and "Traceback" not in proc.stderr


def test_the_card_holds_every_suite_with_every_rate():
    c = card()
    for key in ("mars_yard", "mars_yard_physics", "mars_yard_noise", "craters_unseen", "mars_yard_20"):
        result = c["results"][key]
        assert result["command"].startswith("python -m diana_lab.evaluate policy=pretrained +experiment=reference")
        for rate in RATES:
            assert 0.0 <= result[rate] <= 1.0, (key, rate)
    assert c["training"]["wall_time_min"] > 0 and c["training"]["timesteps"] > 0
    sitemap = c["results_reference_sitemap"]
    for key in ("mars_yard", "mars_yard_physics", "mars_yard_noise", "craters_unseen"):
        result = sitemap[key]
        assert result["command"].startswith(
            "python -m diana_lab.evaluate policy=pretrained +experiment=reference_sitemap"
        )
        for rate in RATES:
            assert 0.0 <= result[rate] <= 1.0, (key, rate)


def pretrained_summary(tmp_path, preset: str, *overrides: str) -> dict:
    """``python -m diana_lab.evaluate policy=pretrained +experiment=<preset> <overrides>`` (no video, no
    tracking) run as a user runs it; its summary JSON."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    out = tmp_path / "summary.json"
    proc = evaluate_cli(
        tmp_path / "run",
        "policy=pretrained",
        f"+experiment={preset}",
        *overrides,
        "eval.video=false",
        "tracking.enabled=false",
        f"output={out}",
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(out.read_text())


@pytest.mark.slow
def test_the_20_episode_suite_gives_what_the_card_says(tmp_path):
    """Deterministic policy, fixed suite: the figures come back (within one episode, for other CPUs' float
    rounding), and they clear the issue's bar for this suite, 90 % success (v0.13 to v0.8: 20 of 20; v0.7 and v0.6: 19;
    v0.5: 18)."""
    want = card()["results"]["mars_yard_20"]
    got = pretrained_summary(tmp_path, "reference", "eval.episodes=20")
    print({k: got[k] for k in RATES})
    assert got["episodes"] == 20
    assert abs(got["success_rate"] - want["success_rate"]) <= 0.05 + 1e-9
    assert abs(got["spl"] - want["spl"]) <= 0.05
    assert got["success_rate"] >= 0.9


@pytest.mark.slow
def test_the_hazard_camera_preset_clears_the_physics_bar_on_the_20_episode_physics_suite(tmp_path):
    """``+experiment=reference_hazcams`` in physics: 19 of the 20 goals on 2026-11-24 (the 100-episode suite 0.92,
    the validation suites 0.96 / 0.93 / 0.90), its route rule deciding; the issue's bar, 90 %, leaves one episode
    for other CPUs' float rounding."""
    got = pretrained_summary(tmp_path, "reference_hazcams", "eval.episodes=20", "eval.dynamics=physics")
    print({k: got[k] for k in ("success_rate", "spl", "tipover_rate", "shield_route_rate")})
    assert got["episodes"] == 20
    assert got["success_rate"] >= 0.9
    assert got["shield_route_rate"] > 0.1  # the route rule, not the policy alone, chose many of the drives


@pytest.mark.slow
def test_with_the_site_map_no_success_of_the_first_35_goals_is_slow(tmp_path):
    """``+experiment=reference_sitemap``: the first 35 goals of the reported suite hold the two that
    ``reference_hazcams`` reaches under the issue's 0.083 m/s (episodes 21 and 34: 0.081 and 0.058 m/s, pockets
    entered blind); with the site map's slopes for unseen ground the search plans round them (2026-11-25: the
    100-episode suite's slowest success 0.11 m/s)."""
    got = pretrained_summary(tmp_path, "reference_sitemap", "eval.episodes=35", "eval.plots=false")
    print({k: got[k] for k in ("success_rate", "spl", "slow_successes", "min_speed_mps", "shield_route_rate")})
    assert got["episodes"] == 35
    assert got["success_rate"] >= 34 / 35
    assert got["slow_successes"] == 0 and got["min_speed_mps"] >= 0.083


@pytest.mark.slow
def test_the_exported_policy_drives_like_torch_on_1000_mars_yard_observations(tmp_path):
    from diana_lab.deploy import Navigator
    from diana_lab.export import main
    from tests.deploy.helpers import record
    from tests.deploy.test_parity import TOLERANCE_M, replay

    onnx = tmp_path / "policy.onnx"
    main.task(compose(["+experiment=reference", "policy=pretrained", f"output={onnx}"], config_name="export"))
    cfg = reference_cfg()
    loaded = load_policy("pretrained", cfg, to_object("eval", cfg.eval))  # behind the preset's slope shield
    env = RoverNavEnv(config=env_config(cfg, None, loaded.train_cfg))
    try:
        rec = record(env, loaded.policy, 1000, seed=7)
    finally:
        env.close()
    nav = Navigator.from_files(onnx)
    err = replay(nav, rec)
    print(f"shipped policy parity over 1000 observations: {err}; vetoes {nav.shield.vetoes}")
    assert err["waypoint"] <= TOLERANCE_M
    assert nav.shield.vetoes == loaded.policy.shield.vetoes > 0  # the sidecar's shield drove it, as in the sim
    assert nav.shield.approaches == loaded.policy.shield.approaches > 0  # its final approach too
    assert nav.shield.detours == loaded.policy.shield.detours > 0  # and its detour
    # not degenerate: the recording spans many episodes and the policy picks many candidates
    assert sum(rec.starts) >= 10
    assert len(np.unique(np.round(np.asarray(rec.waypoints) - np.asarray(rec.poses)[:, :2], 3), axis=0)) > 50


def test_the_preset_drives_it_behind_the_slope_shield_which_only_reorders_its_own_candidates():
    """The first allowed of the policy's own ranking is driven: the policy's choice itself when the shield
    allows it, another of its top_k when not (here forced by a 0-degree limit on a map of a rough start)."""
    from diana_lab.evaluation.policies import ShieldedPolicy

    cfg = reference_cfg()
    loaded = load_policy("pretrained", cfg, to_object("eval", cfg.eval))
    assert isinstance(loaded.policy, ShieldedPolicy) and loaded.policy.name == "pretrained"
    env = RoverNavEnv(config=env_config(cfg, None, loaded.train_cfg))
    try:
        obs, _ = env.reset(seed=3)
        policy = loaded.policy
        policy.reset(env)
        ranking = policy.policy.ranking(obs)
        assert sorted(ranking.tolist()) == list(range(env.action_space.n))  # every candidate, once
        assert int(ranking[0]) == int(policy.policy.act(obs, env))  # its choice first, as predict's
        action = int(policy.act(obs, env))
        base, shield = env.unwrapped, policy.shield
        offsets = base.mapping.world_offsets(base.pose_estimate.yaw)
        xy = base.pose_estimate.xy
        first_allowed = next(int(k) for k in ranking[: shield.cfg.top_k] if shield.allows(xy, offsets[k]))
        assert action == first_allowed
        assert shield.memory.origin is not None  # the reset frame was mapped
        # the tilt check alone (the preset's obstacle check and place rule off: the calls below all stand on the
        # same place, which the rule would remember): nothing the map shows is too steep at 89 deg, so
        # the policy's own choice; at ~0 deg only drives over ground it has not seen (or perfectly level) pass,
        # and the count of vetoes says when it differed
        assert shield.cfg.obstacle_height > 0
        shield.cfg.obstacle_height = 0.0
        assert shield.cfg.revisit_radius > 0
        shield.cfg.revisit_radius = 0.0
        shield.cfg.limit_deg = 89.0
        assert int(policy.act(obs, env)) == int(ranking[0])
        shield.cfg.limit_deg = 1e-9
        before = shield.vetoes
        strict = int(policy.act(obs, env))
        unseen = [int(k) for k in ranking[: shield.cfg.top_k] if shield.steepest_deg(xy, offsets[k]) == 0.0]
        assert strict == (unseen[0] if unseen else int(ranking[0]))
        assert shield.vetoes - before == int(strict != int(ranking[0]))
    finally:
        env.close()


def test_without_the_shield_it_is_the_bare_policy_and_baselines_say_they_run_without_it():
    from diana_lab.evaluation.policies import SB3Policy

    cfg = reference_cfg("eval.shield.enabled=false")
    assert type(load_policy("pretrained", cfg, to_object("eval", cfg.eval)).policy) is SB3Policy
    cfg = reference_cfg()
    loaded = load_policy("straight", cfg, to_object("eval", cfg.eval))
    assert "runs without it" in loaded.note and "eval.shield" in loaded.note


def test_a_shielded_evaluation_reports_how_often_the_shield_changed_course(tmp_path):
    """``shield_vetoes``, ``shield_revisits``, ``shield_fallbacks``, ``shield_approaches`` and ``shield_detours`` per
    episode in the rows, their rates (per step, with intervals) in the summary; all absent without the shield."""
    from diana_lab.evaluation import evaluate

    rates = {}
    for enabled in (True, False):
        cfg = reference_cfg("eval.episodes=3", "eval.video=false", "eval.plots=false", f"eval.shield.enabled={enabled}")
        eval_cfg = to_object("eval", cfg.eval)
        loaded = load_policy("pretrained", cfg, eval_cfg)
        env = RoverNavEnv(config=env_config(cfg, None, loaded.train_cfg))
        try:
            summary = evaluate(loaded.policy, env, eval_cfg, tmp_path / str(enabled))
        finally:
            env.close()
        rows = (tmp_path / str(enabled) / "episodes.csv").read_text().splitlines()
        rates[enabled] = summary.get("shield_veto_rate")
        if enabled:
            vetoes = loaded.policy.shield.vetoes
            assert "shield_vetoes" in rows[0]
            assert summary["shield_veto_rate"] == pytest.approx(vetoes / sum_steps(rows))
            lo, hi = summary["shield_veto_rate_ci95"]
            assert lo <= summary["shield_veto_rate"] <= hi
            # the place rule's share (the preset's eval.shield.revisit_radius), part of the vetoes
            assert "shield_revisits" in rows[0] and loaded.policy.shield.cfg.revisit_radius == 1.0
            revisits = loaded.policy.shield.revisits
            assert summary["shield_revisit_rate"] == pytest.approx(revisits / sum_steps(rows))
            assert 0 <= revisits <= vetoes
            assert "shield_fallbacks" in rows[0]
            fallbacks = loaded.policy.shield.fallbacks
            assert summary["shield_fallback_rate"] == pytest.approx(fallbacks / sum_steps(rows))
            assert fallbacks <= loaded.policy.shield.decisions
            # the final approach (the preset's eval.shield.approach_radius), made on the way to the goals reached
            assert "shield_approaches" in rows[0] and loaded.policy.shield.cfg.approach_radius == 5.0
            approaches = loaded.policy.shield.approaches
            assert summary["shield_approach_rate"] == pytest.approx(approaches / sum_steps(rows))
            assert summary["success_rate"] > 0 and 0 < approaches <= loaded.policy.shield.decisions
            # the detour (the preset's eval.shield.detour_after): its decisions, not counted as vetoes
            assert "shield_detours" in rows[0] and loaded.policy.shield.cfg.detour_after == 4
            detours = loaded.policy.shield.detours
            assert summary["shield_detour_rate"] == pytest.approx(detours / sum_steps(rows))
            assert detours + approaches <= loaded.policy.shield.decisions
            # every veto put down to the checks its policy's choice failed (one can fail several)
            by_check = {c: sum(int(r.split(",")[rows[0].split(",").index(f"shield_{c}_vetoes")]) for r in rows[1:])
                        for c in VETO_CHECKS}  # fmt: skip
            assert by_check == loaded.policy.shield.vetoed_by
            assert all(n <= vetoes for n in by_check.values()) and sum(by_check.values()) >= vetoes
            assert by_check["place"] <= revisits
            for c in VETO_CHECKS:
                assert summary[f"shield_{c}_veto_rate"] == pytest.approx(by_check[c] / sum_steps(rows))
        else:
            assert "shield_vetoes" not in rows[0] and "shield_veto_rate" not in summary
            assert "shield_revisit_rate" not in summary and "shield_fallback_rate" not in summary
            assert "shield_approach_rate" not in summary and "shield_detour_rate" not in summary
            assert not any(f"shield_{c}_veto_rate" in summary for c in VETO_CHECKS)
    assert rates[True] is not None and rates[False] is None


def sum_steps(rows: list[str]) -> int:
    header = rows[0].split(",")
    return sum(int(r.split(",")[header.index("steps")]) for r in rows[1:])


def test_the_hazard_camera_preset_evaluates_it_with_the_relief_check_and_cameras(tmp_path):
    """``+experiment=reference_hazcams`` runs through the CLI: its cameras feed the shield's map, and its route rule
    turns the policy from drives the lidar-only shield lets through (two Mars-yard episodes)."""
    runs = {
        preset: pretrained_summary(tmp_path / preset, preset, "eval.episodes=2", "eval.plots=false")
        for preset in ("reference", "reference_hazcams")
    }
    assert runs["reference"]["shield_relief_veto_rate"] == 0.0
    assert runs["reference"]["shield_route_rate"] == 0.0  # the route rule is the hazard-camera preset's only
    # behind the route rule the policy's own choice is turned from on the ways its map shows, not vetoed
    assert runs["reference_hazcams"]["shield_route_rate"] > 0.1
    assert runs["reference_hazcams"]["success_rate"] == 1.0  # the suite's first two goals, reached either way


def test_the_shipped_card_is_the_current_policys_only():
    """The card in the package describes the policy it ships; earlier versions' figures live in docs/."""
    c = card()
    assert c["version"] and not [k for k in c if "_v0_" in k]
