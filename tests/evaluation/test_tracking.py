"""MLflow: a run id as ``policy=`` loads the runner's artefacts; the evaluation is logged as its child run."""

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from diana_lab.config import compose
from diana_lab.evaluation.tracking import metrics_of
from tests.presets import CAMERA_SQUARE

TINY = [
    *CAMERA_SQUARE,
    "world=flat",
    "world.size_x=20",
    "world.size_y=20",
    "eval.min_distance=4",
    "eval.max_distance=9",
    "eval.episodes=2",
    "eval.video=false",
]


def test_metrics_of_flattens_intervals_and_skips_undefined_values():
    m = metrics_of(
        {
            "episodes": 3,
            "spl": 0.5,
            "spl_ci95": [0.25, 0.75],
            "mean_speed_mps": float("nan"),
            "mean_speed_mps_ci95": [float("nan"), float("nan")],
        }
    )
    assert m == {"eval_episodes": 3.0, "eval_spl": 0.5, "eval_spl_ci95_lo": 0.25, "eval_spl_ci95_hi": 0.75}


def test_run_id_policy_loads_the_model_and_logs_a_child_run(tmp_path, flat_env, monkeypatch):
    mlflow = pytest.importorskip("mlflow")
    from mlflow.tracking import MlflowClient
    from stable_baselines3 import PPO

    from diana_lab.evaluate import run
    from diana_lab.tracking.mlflow_run import resolve_uri

    monkeypatch.chdir(tmp_path)
    uri = resolve_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    train_cfg = compose([*TINY, f"tracking.uri={uri}"])
    model_dir, hydra_dir = tmp_path / "train" / "model", tmp_path / "train" / ".hydra"
    model_dir.mkdir(parents=True)
    hydra_dir.mkdir()
    PPO(
        "MultiInputPolicy",
        flat_env,
        n_steps=8,
        batch_size=8,
        policy_kwargs={"net_arch": [8]},
        device="cpu",
        seed=0,
    ).save(model_dir / "model.zip")
    OmegaConf.save(train_cfg, hydra_dir / "config.yaml")
    mlflow.set_tracking_uri(uri)
    exp = MlflowClient().create_experiment("diana_lab", artifact_location=(tmp_path / "mlruns").as_uri())
    with mlflow.start_run(experiment_id=exp) as parent:  # what the training runner logs
        mlflow.set_tags({"algo": "ppo", "seed": "3", "host_cpu": "Some CPU @ 1.0GHz"})
        mlflow.log_artifact(str(model_dir / "model.zip"), "model")
        mlflow.log_artifact(str(hydra_dir / "config.yaml"), ".hydra")
    parent_id = parent.info.run_id

    cfg = compose([*TINY, f"tracking.uri={uri}", f"policy={parent_id}"], config_name="evaluate")
    out = Path(tmp_path / "eval")
    out.mkdir()
    summary = run(cfg, out)
    assert summary["episodes"] == 2

    client = MlflowClient(uri)
    children = client.search_runs([exp], filter_string=f"tags.mlflow.parentRunId = '{parent_id}'")
    assert len(children) == 1
    child = children[0]
    assert child.data.metrics["eval_episodes"] == 2.0 and "eval_success_rate" in child.data.metrics
    # what the weights were trained as and on: a comparison pairs evaluations by these
    assert {k: child.data.tags.get(k) for k in ("algo", "seed", "host_cpu")} == {
        "algo": "ppo",
        "seed": "3",
        "host_cpu": "Some CPU @ 1.0GHz",
    }
    artefacts = {a.path for a in client.list_artifacts(child.info.run_id)}
    assert {"summary.json", "episodes.csv", "trajectories.png"} <= artefacts
