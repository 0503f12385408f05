"""``python -m diana_lab.evaluate`` in subprocesses: outputs, determinism across processes, user errors."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from diana_lab.evaluation.metrics import SUMMARY_KEYS
from tests.presets import CAMERA_SQUARE

ROOT = Path(__file__).resolve().parents[2]
TINY = [
    *CAMERA_SQUARE,
    "world=flat",
    "world.size_x=20",
    "world.size_y=20",
    "eval.min_distance=4",
    "eval.max_distance=9",
    "tracking.enabled=false",
]


def evaluate_cli(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run(
        [sys.executable, "-m", "diana_lab.evaluate", *args, f"hydra.run.dir={tmp}"],
        cwd=tmp.parent,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_cli_writes_the_summary_json_with_every_key(tmp_path):
    out = tmp_path / "result" / "straight.json"
    proc = evaluate_cli(
        tmp_path / "run",
        "policy=straight",
        "world=flat",
        "eval.episodes=3",
        "tracking.enabled=false",
        f"output={out}",
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(out.read_text())
    for key in SUMMARY_KEYS:
        assert key in summary
    assert summary["episodes"] == 3
    assert (tmp_path / "run" / "summary.json").read_text() == out.read_text()
    assert "success_rate" in proc.stdout  # the printed table


def test_same_seed_gives_a_byte_identical_summary_in_two_processes(tmp_path):
    # noisy sensor and pose: the per-episode reset seeds must reproduce the noise too
    args = [
        "policy=astar",
        *TINY,
        "eval.episodes=4",
        "eval.seed=77",
        "eval.video=false",
        "eval.plots=false",
        "sensor.noise=realistic",
        "dynamics.pose_noise.position_std=0.05",
    ]
    first = evaluate_cli(tmp_path / "a", *args, f"output={tmp_path / 'a.json'}")
    second = evaluate_cli(tmp_path / "b", *args, f"output={tmp_path / 'b.json'}")
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert (tmp_path / "a" / "episodes.csv").read_bytes() == (tmp_path / "b" / "episodes.csv").read_bytes()


def test_a_missing_model_file_exits_2_naming_the_path(tmp_path):
    proc = evaluate_cli(tmp_path / "run", "policy=no/such/model.zip", *TINY)
    assert proc.returncode == 2
    assert "no/such/model.zip" in proc.stderr and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: ")


def test_a_dynamics_group_chosen_on_the_command_line_is_not_replaced_by_the_trainings():
    """``policy=pretrained dynamics=physics``: the shipped policy was trained kinematic, and with ``eval.dynamics``
    null the training's dynamics used to win without a word; the group chosen counts as ``eval.dynamics``, and
    keeps its own settings."""
    from diana_lab.config import compose
    from diana_lab.evaluate import chosen_dynamics, env_config

    trained = compose(["+experiment=reference"])
    assert trained.dynamics.name == "kinematic"
    overrides = ["policy=pretrained", "+experiment=reference", "dynamics=physics", "dynamics.time_step=0.01"]
    cfg = compose(overrides[1:])
    chosen_dynamics(cfg, overrides)
    assert cfg.eval.dynamics == "physics"
    env_cfg = env_config(cfg, cfg.eval.dynamics, trained)
    assert env_cfg.dynamics.name == "physics" and env_cfg.dynamics.time_step == 0.01
    # without the choice on the command line the training's dynamics stands, as documented
    plain = compose(["+experiment=reference"])
    chosen_dynamics(plain, ["policy=pretrained", "+experiment=reference", "eval.episodes=3"])
    assert plain.eval.dynamics is None
    physics_trained = compose(["+experiment=reference", "dynamics=physics"])
    assert env_config(plain, None, physics_trained).dynamics.name == "physics"


def test_a_dynamics_group_and_an_eval_dynamics_that_disagree_exit_2_naming_both(tmp_path):
    proc = evaluate_cli(tmp_path / "run", "policy=straight", *TINY, "dynamics=physics", "eval.dynamics=kinematic")
    assert proc.returncode == 2, proc.stderr
    assert "dynamics=physics" in proc.stderr and "eval.dynamics=kinematic" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_dynamics_settings_without_a_group_are_laid_over_the_trainings_dynamics():
    """``policy=pretrained dynamics.pose_noise.position_std=0.2``: the training's dynamics replaces the command
    line's, and used to take the setting with it without a word."""
    from diana_lab.cli import UserError
    from diana_lab.config import compose
    from diana_lab.evaluate import chosen_dynamics, env_config

    trained = compose(["+experiment=reference"])
    assert trained.dynamics.pose_noise.position_std != 0.2
    overrides = ["policy=pretrained", "+experiment=reference", "dynamics.pose_noise.position_std=0.2"]
    cfg = compose(overrides[1:])
    keys = chosen_dynamics(cfg, overrides)
    assert keys == ["dynamics.pose_noise.position_std"] and cfg.eval.dynamics is None
    env_cfg = env_config(cfg, None, trained, keys)
    assert env_cfg.dynamics.name == trained.dynamics.name
    assert env_cfg.dynamics.pose_noise.position_std == 0.2
    assert trained.dynamics.pose_noise.position_std != 0.2  # the training's config is not changed

    # a setting the training's dynamics does not have: physics-only keys on a kinematic-trained policy
    physics_only = ["policy=pretrained", "dynamics.time_step=0.01"]
    cfg = compose(["dynamics=physics", "dynamics.time_step=0.01"])
    keys = chosen_dynamics(cfg, physics_only)
    assert keys == ["dynamics.time_step"]
    with pytest.raises(UserError, match=r"dynamics\.time_step.*kinematic"):
        env_config(cfg, None, trained, keys)


def test_the_pretrained_policy_on_another_action_space_exits_2_naming_the_key(tmp_path):
    """``action_space.headings=64`` used to run silently (the policy's indices meaning other waypoints); the
    preset hint stays out when the preset was given (the differing key is the point)."""
    proc = evaluate_cli(
        tmp_path / "run",
        "policy=pretrained",
        "+experiment=reference",
        *TINY[-1:],
        "action_space.headings=64",
        "eval.episodes=1",
    )
    assert proc.returncode == 2, proc.stderr
    assert "action_space.headings: training 32, here 64" in proc.stderr
    assert "+experiment=reference" not in proc.stderr and "Traceback" not in proc.stderr


def test_evaluating_on_another_robot_than_the_trainings_is_said(tmp_path):
    flat = TINY[len(CAMERA_SQUARE) :]  # the small world, not the camera set-up: the preset picks the sensor
    proc = evaluate_cli(
        tmp_path / "run", "policy=pretrained", "+experiment=reference", "robot=husky", *flat, "eval.episodes=1"
    )
    assert proc.returncode == 0, proc.stderr
    assert "trained on robot=jackal; evaluating it on robot=husky" in proc.stdout


def test_evaluating_with_another_lidar_mount_than_the_trainings_is_said(tmp_path):
    """Observations of the same shape from a lidar mounted elsewhere: it runs, and says so."""
    flat = TINY[len(CAMERA_SQUARE) :]
    proc = evaluate_cli(
        tmp_path / "run", "policy=pretrained", "+experiment=reference", "sensor.mount_xyz=[0.0,0.0,0.3]", *flat,
        "eval.episodes=1",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "sensor.mount_xyz: training [0.0, 0.0, 0.5], here [0.0, 0.0, 0.3]" in proc.stdout


def test_a_run_evaluated_without_its_trainings_overrides_is_told_which_to_add(tmp_path):
    """``policy=<run id of a +experiment=quick run>`` without the preset was refused naming only the config keys
    that differ; the message ends with the training's own overrides to add, and adding them is enough."""
    from mlflow.tracking import MlflowClient

    from tests.reliability.helpers import QUIET, TINY_BUDGET, run_cli

    store = [f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"]
    budget = [*TINY_BUDGET, *QUIET]  # +experiment=quick, trained for one tiny update
    trained = run_cli("diana_lab", ["+experiment=quick", *budget, *store, f"hydra.run.dir={tmp_path}/train"], tmp_path)
    assert trained.returncode == 0, trained.stderr
    client = MlflowClient(store[0].split("=", 1)[1])
    (run,) = client.search_runs([client.get_experiment_by_name("diana_lab").experiment_id])

    args = [f"policy={run.info.run_id}", *store, "tracking.enabled=false", "eval.episodes=1", "eval.plots=false"]
    proc = evaluate_cli(tmp_path / "plain", *args)
    assert proc.returncode == 2, proc.stderr
    message = proc.stderr.split("\n(set HYDRA_FULL_ERROR")[0]
    assert "sensor._target_: training 'diana_lab.sensing.camera.DepthCamera'" in message and "Traceback" not in message
    assert message.endswith("Re-run with the training's overrides: +experiment=quick"), message
    proc = evaluate_cli(tmp_path / "with_preset", *args, "+experiment=quick")
    assert proc.returncode == 0, proc.stderr


def test_the_bearing_ranking_drives_behind_the_presets_shield_in_the_networks_place(tmp_path):
    """``policy=bearing +experiment=reference``: the non-learnt ranking behind the same shield (its counters in
    the summary), so what the network adds there is one command away."""
    out = tmp_path / "bearing.json"
    proc = evaluate_cli(
        tmp_path / "run",
        "policy=bearing",
        "+experiment=reference",
        "eval.episodes=3",
        "eval.video=false",
        "eval.plots=false",
        "tracking.enabled=false",
        f"output={out}",
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(out.read_text())
    assert summary["episodes"] == 3
    assert "shield_veto_rate" in summary and "runs without it" not in proc.stderr + proc.stdout
