"""``python -m diana_lab`` end to end with tiny budgets: MLflow runs, artefacts, resume, multirun, errors."""

from __future__ import annotations

import pytest
from hydra.utils import get_class

from diana_lab.tracking.host import cpu_model

from .helpers import ALGO_TINY, TINY, run_in_process, runs, store_args

CLASSES = {
    "ppo": "stable_baselines3.PPO",
    "a2c": "stable_baselines3.A2C",
    "sac": "stable_baselines3.SAC",
    "td3": "stable_baselines3.TD3",
    "ddpg": "stable_baselines3.DDPG",
    "tqc": "sb3_contrib.TQC",
}


@pytest.mark.parametrize("algo", list(ALGO_TINY))
def test_run_finishes_with_params_metrics_and_loadable_model(algo, tmp_path):
    code = run_in_process([f"algo={algo}", *TINY, *ALGO_TINY[algo], *store_args(tmp_path)])
    assert code == 0
    client, found = runs(tmp_path)
    assert len(found) == 1
    run = found[0]
    assert run.info.status == "FINISHED"
    assert run.data.tags["algo"] == algo and run.data.tags["world"] == "flat"
    assert run.data.tags["sensor"] == "depth_camera" and run.data.tags["dynamics"] == "kinematic"
    assert f"algo={algo}" in run.data.tags["overrides"] and run.data.tags["git_commit"]
    assert run.data.tags["host_cpu"] == cpu_model()  # a seed reproduces on one kind of CPU only
    assert run.data.params["algo.name"] == algo and run.data.params["train.total_timesteps"] == "256"
    assert run.data.params["sensor.width"] == "16"
    metrics = run.data.metrics
    assert "eval_success_rate" in metrics and "eval_spl" in metrics
    assert "time/fps" in metrics and "rollout/ep_rew_mean" in metrics
    assert "train/reward_progress" in metrics and "train/outcome_timeout" in metrics
    history = client.get_metric_history(run.info.run_id, "eval_success_rate")
    assert max(m.step for m in history) >= 256  # step = timesteps
    artefacts = {a.path for a in client.list_artifacts(run.info.run_id)}
    assert {"model", "best", "checkpoints", "eval", ".hydra", "config_resolved.yaml"} <= artefacts
    eval_files = {a.path for a in client.list_artifacts(run.info.run_id, "eval")}
    assert {"eval/episodes.csv", "eval/summary.json"} <= eval_files
    local = client.download_artifacts(run.info.run_id, "model/model.zip", str(tmp_path / "dl"))
    model = get_class(CLASSES[algo]).load(local, device="cpu")
    assert model.num_timesteps >= 256


@pytest.mark.parametrize(("final_eval", "steps"), [(True, [128, 256]), (False, [128, 256])])
def test_an_evaluation_due_at_the_budget_is_left_to_the_final_one(final_eval, steps, tmp_path):
    """Periodic evaluations every 128 steps of a 256-step run: with the final evaluation on, the one due at the
    budget is skipped (the final one follows on the same suite); with it off, the periodic one is the last."""
    args = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], f"train.final_eval={str(final_eval).lower()}"]
    assert run_in_process([*args, *store_args(tmp_path)]) == 0
    client, found = runs(tmp_path)
    history = client.get_metric_history(found[0].info.run_id, "eval_success_rate")
    assert sorted(m.step for m in history) == steps


@pytest.mark.parametrize(("algo", "extra"), [("ppo", ["algo.normalize=true"]), ("sac", [])])
def test_resume_continues_step_counter_and_run(algo, extra, tmp_path):
    base = [f"algo={algo}", *TINY, *ALGO_TINY[algo], *extra, "eval.every=0", "train.final_eval=false"]
    assert run_in_process([*base, *store_args(tmp_path, "first")]) == 0
    client, (run,) = runs(tmp_path)
    resume = ["train.total_timesteps=512", f"train.resume={run.info.run_id}", *store_args(tmp_path, "second")]
    assert run_in_process([*base, *resume]) == 0
    client, found = runs(tmp_path)
    assert len(found) == 1  # the same MLflow run, not a new one
    run = client.get_run(run.info.run_id)
    assert run.info.status == "FINISHED" and "resumed_from" in run.data.tags
    steps = sorted(m.step for m in client.get_metric_history(run.info.run_id, "time/total_timesteps"))
    assert steps[0] < 256 < steps[-1]  # counted on from the first run, not restarted
    ckpts = {a.path for a in client.list_artifacts(run.info.run_id, "checkpoints")}
    assert "checkpoints/rl_model_256_steps.zip" in ckpts and "checkpoints/rl_model_512_steps.zip" in ckpts
    model_files = {a.path for a in client.list_artifacts(run.info.run_id, "model")}
    if algo == "ppo":  # VecNormalize statistics travel with every model
        assert "checkpoints/rl_model_vecnormalize_512_steps.pkl" in ckpts
        assert "model/vecnormalize.pkl" in model_files
    else:  # the replay buffer stays local (only the newest one)
        assert [p.name for p in (tmp_path / "second" / "checkpoints").glob("*replay_buffer*")] == [
            "rl_model_replay_buffer_512_steps.pkl"
        ]


def test_resume_from_run_dir_and_finished_budget_is_a_clear_error(tmp_path, capsys):
    base = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], "eval.every=0", "train.final_eval=false"]
    assert run_in_process([*base, *store_args(tmp_path, "first")]) == 0
    client, (run,) = runs(tmp_path)
    capsys.readouterr()
    for spec in (f"{tmp_path}/first", run.info.run_id):
        assert run_in_process([*base, f"train.resume={spec}", *store_args(tmp_path, "again")]) == 2
        assert "the resumed model has already trained 256 steps" in capsys.readouterr().err
    # refused before the finished run was reopened: it did not end FAILED, nor lose its run dir to the new one
    after = client.get_run(run.info.run_id)
    assert after.info.status == "FINISHED" and after.data.tags["run_dir"] == f"{tmp_path}/first"


def test_resuming_an_older_checkpoint_of_a_run_that_went_on_branches_into_a_new_run(tmp_path, capsys):
    """The run was resumed from 256 to 512 steps elsewhere; resuming its first folder again (256 steps) used to
    log 256..512 a second time into the same run, over the history it had."""
    base = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], "eval.every=0", "train.final_eval=false"]
    assert run_in_process([*base, *store_args(tmp_path, "first")]) == 0
    client, (run,) = runs(tmp_path)
    on = ["train.total_timesteps=512", f"train.resume={run.info.run_id}", *store_args(tmp_path, "second")]
    assert run_in_process([*base, *on]) == 0
    history = sorted(m.step for m in client.get_metric_history(run.info.run_id, "time/total_timesteps"))
    capsys.readouterr()
    again = ["train.total_timesteps=512", f"train.resume={tmp_path}/first", *store_args(tmp_path, "third")]
    assert run_in_process([*base, *again]) == 0
    assert f"its MLflow run {run.info.run_id} went on to 512" in capsys.readouterr().out
    _, found = runs(tmp_path)
    (branch,) = [r for r in found if r.info.run_id != run.info.run_id]
    assert branch.data.tags["branched_from"] == run.info.run_id and branch.info.status == "FINISHED"
    steps = sorted(m.step for m in client.get_metric_history(branch.info.run_id, "time/total_timesteps"))
    assert steps[0] > 256 and steps[-1] >= 512  # counted on from the older checkpoint, in the new run
    after = client.get_run(run.info.run_id)  # the original run as it was
    assert sorted(m.step for m in client.get_metric_history(run.info.run_id, "time/total_timesteps")) == history
    assert after.data.tags["run_dir"] == f"{tmp_path}/second"


def test_resume_by_run_id_downloads_the_checkpoint_when_the_run_dir_is_gone(tmp_path):
    base = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], "algo.normalize=true", "eval.every=0", "train.final_eval=false"]
    assert run_in_process([*base, *store_args(tmp_path, "first")]) == 0
    client, (run,) = runs(tmp_path)
    (tmp_path / "first").rename(tmp_path / "moved")  # another machine, a cleaned-up outputs/ folder
    resume = ["train.total_timesteps=512", f"train.resume={run.info.run_id}", *store_args(tmp_path, "second")]
    assert run_in_process([*base, *resume]) == 0
    assert sorted(p.name for p in (tmp_path / "second" / "resume" / "checkpoints").iterdir()) == [
        "rl_model_256_steps.zip",
        "rl_model_vecnormalize_256_steps.pkl",
    ]
    after = client.get_run(run.info.run_id)
    assert after.info.status == "FINISHED" and after.data.tags["resumed_from"].endswith("(downloaded checkpoint)")
    steps = sorted(m.step for m in client.get_metric_history(run.info.run_id, "time/total_timesteps"))
    assert steps[0] < 256 < steps[-1]  # counted on from the downloaded checkpoint


def test_resume_in_another_env_is_refused_or_reported_naming_the_keys(tmp_path, capsys):
    """Other observations: refused before any MLflow run, naming the setting (SB3 named only the spaces, once the
    run was open). Another reward: allowed (fine-tuning), but printed and tagged, not silent."""
    base = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], "eval.every=0", "train.final_eval=false"]
    assert run_in_process([*base, *store_args(tmp_path, "first")]) == 0
    client, (run,) = runs(tmp_path)
    capsys.readouterr()
    resume = ["train.total_timesteps=512", f"train.resume={run.info.run_id}"]
    assert run_in_process([*base, "sensor.width=32", *resume, *store_args(tmp_path, "wider")]) == 2
    err = capsys.readouterr().err
    assert "observation space" in err and "sensor.width: training 16, here 32" in err
    assert client.get_run(run.info.run_id).info.status == "FINISHED"  # the run was not reopened and failed
    # a training override left out: the message ends with it, ready to paste
    without = [a for a in base if a != "sensor.width=16"]
    assert run_in_process([*without, *resume, *store_args(tmp_path, "narrower")]) == 2
    err = capsys.readouterr().err.split("\n(set HYDRA_FULL_ERROR")[0]
    assert err.endswith("Re-run with the training's overrides: sensor.width=16"), err

    assert run_in_process([*base, "reward.terms.goal.weight=20", *resume, *store_args(tmp_path, "second")]) == 0
    assert "reward.terms.goal.weight: training 10.0, here 20" in capsys.readouterr().out
    tags = client.get_run(run.info.run_id).data.tags
    assert "reward.terms.goal.weight: training 10.0, here 20" in tags["resume_config_changes"]


def test_eval_sensor_noise_sweeps_the_final_evaluation(tmp_path, capsys):
    """It used to be ignored by training without a word."""
    base = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], "train.total_timesteps=64", "eval.every=0", "eval.episodes=1"]
    assert run_in_process([*base, "eval.sensor_noise=[0,1]", *store_args(tmp_path, "first")]) == 0
    client, (run,) = runs(tmp_path)
    for level in ("0", "1"):
        assert f"eval_noise_{level}_success_rate" in run.data.metrics
    names = {a.path for a in client.list_artifacts(run.info.run_id, "eval/sensor_noise")}
    assert {"eval/sensor_noise/sensor_noise.csv", "eval/sensor_noise/noise_1"} <= names
    capsys.readouterr()
    off = ["eval.sensor_noise=[1]", "train.final_eval=false", *store_args(tmp_path, "second")]
    assert run_in_process([*base, *off]) == 2
    assert "eval.sensor_noise=[1.0]: sweeps the final evaluation" in capsys.readouterr().err


def test_multirun_gives_one_run_per_job(tmp_path):
    args = [
        "-m",
        "algo=ppo",
        "seed=0,1",
        *TINY,
        *ALGO_TINY["ppo"],
        "train.total_timesteps=64",
        "eval.every=0",
        "train.final_eval=false",
        f"tracking.uri=sqlite:///{tmp_path}/mlflow.db",
        f"hydra.sweep.dir={tmp_path}/multi",
    ]
    assert run_in_process(args) == 0
    _, found = runs(tmp_path)
    assert sorted(r.data.tags["seed"] for r in found) == ["0", "1"]
    assert all(r.info.status == "FINISHED" for r in found)
    assert {r.data.tags["run_dir"] for r in found} == {f"{tmp_path}/multi/0", f"{tmp_path}/multi/1"}


def test_tracking_disabled_writes_no_store(tmp_path):
    args = [
        "algo=ppo",
        *TINY,
        *ALGO_TINY["ppo"],
        "train.total_timesteps=64",
        "eval.every=0",
        "train.final_eval=false",
        "tracking.enabled=false",
        *store_args(tmp_path),
    ]
    assert run_in_process(args) == 0
    assert not (tmp_path / "mlflow.db").exists()
    assert (tmp_path / "run" / "model" / "model.zip").is_file()


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("train.n_envs=0", "train.n_envs"),
        ("train.vec_env=threads", "train.vec_env"),
        ("train.resume=/no/such/dir", "train.resume"),
    ],
)
def test_bad_values_exit_2_without_a_run(override, message, tmp_path, capsys):
    assert run_in_process(["algo=ppo", *TINY, override, *store_args(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not runs(tmp_path)[1]  # validated before any MLflow run is opened


def test_the_slope_shield_on_continuous_waypoints_exits_2_naming_both_keys(tmp_path, capsys):
    args = ["algo=ppo", "eval.shield.enabled=true", *TINY, *ALGO_TINY["ppo"], "action_space=square"]
    args += store_args(tmp_path)
    assert run_in_process(args) == 2
    err = capsys.readouterr().err
    assert "eval.shield.enabled with action_space.shape=square" in err and "Traceback" not in err
    assert not runs(tmp_path)[1]


def test_an_overlapped_run_evaluates_checkpoints_and_resumes_as_a_plain_one(tmp_path):
    """train.overlap=true: the same evaluation steps, checkpoints and counters as without, and train.resume
    continues it (the rollouts after the first are collected during the updates, diana_lab/agents/overlap.py)."""
    args = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], "train.total_timesteps=384", "train.overlap=true"]
    assert run_in_process([*args, *store_args(tmp_path)]) == 0
    client, (run,) = runs(tmp_path)
    assert run.info.status == "FINISHED" and run.data.params["train.overlap"] == "True"
    history = client.get_metric_history(run.info.run_id, "eval_success_rate")
    assert sorted(m.step for m in history) == [128, 256, 384]
    checkpoints = sorted(p.name for p in (tmp_path / "run" / "checkpoints").glob("*.zip"))
    assert checkpoints == ["rl_model_128_steps.zip", "rl_model_256_steps.zip", "rl_model_384_steps.zip"]
    resumed = [*args[:-2], "train.total_timesteps=640", "train.overlap=true", f"train.resume={tmp_path}/run"]
    assert run_in_process([*resumed, *store_args(tmp_path, "run2")]) == 0
    model = get_class(CLASSES["ppo"]).load(tmp_path / "run2" / "model" / "model.zip", device="cpu")
    assert model.num_timesteps == 640


def test_overlapping_an_off_policy_algorithm_exits_2_naming_the_key(tmp_path, capsys):
    args = ["algo=sac", *TINY, *ALGO_TINY["sac"], "train.overlap=true", *store_args(tmp_path)]
    assert run_in_process(args) == 2
    err = capsys.readouterr().err
    assert "train.overlap=true: algo=sac is off-policy" in err and "Traceback" not in err
    assert not runs(tmp_path)[1]


def test_an_algo_that_cannot_drive_discrete_waypoints_exits_2_naming_both_keys(tmp_path, capsys):
    args = ["algo=sac", *TINY, *ALGO_TINY["sac"], "action_space=discrete", *store_args(tmp_path)]
    assert run_in_process(args) == 2
    err = capsys.readouterr().err
    assert "algo=sac with action_space.shape=discrete" in err and "Traceback" not in err
    assert not runs(tmp_path)[1]


def test_discrete_waypoints_train_through_imitation_ppo_and_evaluation(tmp_path):
    args = [
        "algo=ppo",
        "action_space=discrete",
        *TINY,
        *ALGO_TINY["ppo"],
        "algo.normalize=true",
        "train.imitation.enabled=true",
        "train.imitation.iterations=2",
        "train.imitation.steps_per_iteration=64",
        "eval.shield.enabled=true",  # its evaluations drive behind the slope shield
        *store_args(tmp_path),
    ]
    assert run_in_process(args) == 0
    client, (run,) = runs(tmp_path)
    assert run.info.status == "FINISHED" and run.data.params["action_space.shape"] == "discrete"
    assert run.data.params["eval.shield.enabled"] == "True"
    assert run.data.tags["imitation_steps"] == "128" and "eval_success_rate" in run.data.metrics
    assert {m.step for m in client.get_metric_history(run.info.run_id, "imitation/loss")} == {0, 1}
    local = client.download_artifacts(run.info.run_id, "model/model.zip", str(tmp_path / "dl"))
    model = get_class(CLASSES["ppo"]).load(local, device="cpu")
    assert model.num_timesteps >= 256 and model.action_space.n == 48


def test_subprocess_envs_train_and_stop_cleanly(tmp_path):
    args = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], "train.vec_env=subproc", "train.total_timesteps=128", "eval.every=0"]
    assert run_in_process([*args, "train.final_eval=false", *store_args(tmp_path)]) == 0
    _, (run,) = runs(tmp_path)
    assert run.info.status == "FINISHED" and run.data.params["train.vec_env"] == "subproc"
    assert run.data.metrics["time/total_timesteps"] >= 128


def test_same_seed_same_model_other_seed_other_model(tmp_path):
    import torch
    from stable_baselines3 import PPO

    def trained(seed: int, name: str) -> dict:
        args = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], "train.total_timesteps=128", "eval.every=0"]
        args += [f"seed={seed}", "train.final_eval=false", "tracking.enabled=false", f"hydra.run.dir={tmp_path}/{name}"]
        assert run_in_process(args) == 0
        return PPO.load(tmp_path / name / "model" / "model.zip", device="cpu").policy.state_dict()

    a, b, c = trained(0, "a"), trained(0, "b"), trained(1, "c")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_runs_started_without_hydra_are_tagged_with_each_group(tmp_path):
    """Notebooks and sweeps call ``train`` directly: tags still name the chosen worlds, robots, sensors..."""
    from diana_lab.config import compose
    from diana_lab.training import train
    from diana_lab.training.context import RunContext

    cfg = compose([*TINY, *ALGO_TINY["ppo"], "robot=husky", f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"])
    train(cfg, RunContext(tmp_path / "run"))
    _, found = runs(tmp_path)
    tags = found[0].data.tags
    assert (tags["world"], tags["robot"], tags["sensor"], tags["algo"]) == ("flat", "husky", "depth_camera", "ppo")
