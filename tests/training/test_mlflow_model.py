"""The trained policy as an MLflow model: logged by every run (final and best), loadable with
``mlflow.pyfunc.load_model`` in a fresh process, registered with ``tracking.register_model``, and read back by
``python -m diana_lab.evaluate`` / ``python -m diana_lab.export`` as ``policy=models:/<name>/<version>`` or
``models:/<name>@<alias>``."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from diana_lab.config import ConfigError, compose, to_object
from diana_lab.config.evaluation import EvalConfig
from diana_lab.envs.action_spaces import WaypointMapping
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.errors import UserError
from diana_lab.evaluation.loading import load_policy
from diana_lab.tracking.pyfunc_model import BEST_MODEL, FINAL_MODEL, PolicyModel, _policy_folder
from tests import entrypoints

from .helpers import ALGO_TINY, TINY, run_in_process, runs, store_args

NAME = "rover_nav"
# the env of TINY's training, for the evaluation and the recorded observations
ENV = ["world=flat", "sensor=depth_camera", "robot.tilt_guard_deg=null", "sensor.width=16", "sensor.height=12"]
EVAL_ARGS = ["eval.episodes=1", "eval.plots=false", "eval.video=false"]
LOGGING = ["hydra/job_logging=disabled", "hydra/hydra_logging=disabled"]

FRESH_PROCESS = textwrap.dedent(
    """
    import sys

    import mlflow
    import numpy as np

    mlflow.set_tracking_uri(sys.argv[1])
    model = mlflow.pyfunc.load_model(sys.argv[2])
    data = np.load(sys.argv[3])
    out = model.predict({k: data[k] for k in data.files})
    np.savez(sys.argv[4], **out)
    """
)


class Trained:
    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.uri = f"sqlite:///{tmp}/mlflow.db"
        args = ["algo=ppo", *TINY, *ALGO_TINY["ppo"], *store_args(tmp), f"tracking.register_model={NAME}"]
        console = io.StringIO()
        with contextlib.redirect_stdout(console), contextlib.redirect_stderr(console):
            assert run_in_process(args) == 0
        self.console = console.getvalue()
        self.client, (run,) = runs(tmp)
        self.run = run
        self.run_id = run.info.run_id
        self.cfg = OmegaConf.load(tmp / "run" / ".hydra" / "config.yaml")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    return Trained(tmp_path_factory.mktemp("mlflow_model"))


@pytest.fixture(scope="module")
def recorded(trained):
    """Observations of the training's env under random actions, with the pose estimate's yaw at each."""
    env = RoverNavEnv(config=compose([*ENV, "episode.max_steps=20"]))
    env.action_space.seed(3)
    obs, _ = env.reset(seed=3)
    observations, yaws = [], []
    for _ in range(12):
        observations.append(obs)
        yaws.append(env.pose_estimate.yaw)
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            obs, _ = env.reset()
    env.close()
    batch = {k: np.stack([o[k] for o in observations]) for k in observations[0]}
    return batch, observations, np.array(yaws)


def expected_waypoints(trained, observations, yaws):
    """The run's SB3 model, loaded from its ``model/`` artefacts (the evaluation's loader), one observation at a
    time: its deterministic actions and the env's mapping of them."""
    loaded = load_policy(trained.run_id, compose([f"tracking.uri={trained.uri}"]), EvalConfig())
    mapping = WaypointMapping(to_object("action_space", loaded.train_cfg.action_space))
    actions = [loaded.policy.act(o, None) for o in observations]
    local = np.stack([mapping.offset(a, 0.0) for a in actions])
    world = np.stack([mapping.offset(a, y) for a, y in zip(actions, yaws)])
    return np.array(actions), local, world


def test_a_run_logs_its_final_and_best_policy_as_mlflow_models_with_a_signature(trained):
    import mlflow

    mlflow.set_tracking_uri(trained.uri)
    for name in (FINAL_MODEL, BEST_MODEL):
        info = mlflow.models.get_model_info(f"runs:/{trained.run_id}/{name}")
        assert info.run_id == trained.run_id
        inputs = {s.name: s for s in info.signature.inputs.inputs}
        assert set(inputs) == {"goal", "depth_image"}
        assert tuple(inputs["goal"].shape) == (-1, 7) and tuple(inputs["depth_image"].shape) == (-1, 1, 12, 16)
        assert [s.name for s in info.signature.outputs.inputs] == ["offset", "local_offset", "action"]
        assert info.saved_input_example_info is not None
    # the run's own artefacts, which policy=<run id> and train.resume read, are where they were
    names = {a.path for a in trained.client.list_artifacts(trained.run_id, "model")}
    assert "model/model.zip" in names


def test_logging_the_models_draws_no_download_bars_on_the_console(trained):
    # Model.log loads each model back to check its input example; MLflow's bars for that would be lines of
    # carriage returns in a job's log, between the progress lines and the summary
    assert "MLflow run id" in trained.console  # the console was captured: the run's summary is there
    assert "Downloading artifacts" not in trained.console


def test_a_fresh_process_loads_the_model_and_gets_the_sb3_models_waypoints(trained, recorded, tmp_path):
    batch, observations, yaws = recorded
    np.savez(tmp_path / "obs.npz", **batch)
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            FRESH_PROCESS,
            trained.uri,
            f"runs:/{trained.run_id}/{FINAL_MODEL}",
            str(tmp_path / "obs.npz"),
            str(tmp_path / "out.npz"),
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = np.load(tmp_path / "out.npz")
    actions, local, world = expected_waypoints(trained, observations, yaws)
    np.testing.assert_array_equal(out["action"], actions)
    np.testing.assert_allclose(out["local_offset"], local, atol=1e-12)
    # the world-frame offset the env drives: turned by the yaw of the observation's goal vector (float32)
    np.testing.assert_allclose(out["offset"], world, atol=1e-5)
    assert out["offset"].shape == (len(observations), 2)


def test_register_model_adds_a_version_evaluate_loads_by_version_and_alias(trained, recorded):
    batch, observations, yaws = recorded
    versions = trained.client.search_model_versions(f"name = '{NAME}'")
    assert [(str(v.version), v.run_id) for v in versions] == [("1", trained.run_id)]
    assert trained.client.get_run(trained.run_id).data.tags["registered_model"] == f"{NAME}/1"
    trained.client.set_registered_model_alias(NAME, "champion", "1")
    actions, _, _ = expected_waypoints(trained, observations, yaws)
    cfg = compose([f"tracking.uri={trained.uri}"])
    for spec in (f"models:/{NAME}/1", f"models:/{NAME}@champion"):
        loaded = load_policy(spec, cfg, EvalConfig())
        assert loaded.run_id == trained.run_id and loaded.train_cfg is not None
        assert loaded.label == spec and loaded.run_id in loaded.note
        np.testing.assert_array_equal([loaded.policy.act(o, None) for o in observations], actions)


def test_evaluate_and_export_take_a_registered_version_on_the_command_line(trained, tmp_path):
    trained.client.set_registered_model_alias(NAME, "staging", "1")
    store = [f"tracking.uri={trained.uri}"]
    code = entrypoints.run_in_process(
        "diana_lab.evaluate",
        [f"policy=models:/{NAME}@staging", *ENV, *EVAL_ARGS, *store, *LOGGING, f"hydra.run.dir={tmp_path}/eval"],
    )
    assert code == 0
    children = trained.client.search_runs(
        [trained.run.info.experiment_id], f"tags.mlflow.parentRunId = '{trained.run_id}'"
    )
    assert len(children) == 1 and "eval_success_rate" in children[0].data.metrics

    onnx = tmp_path / "policy.onnx"
    args = [f"policy=models:/{NAME}/1", f"output={onnx}", *store, *LOGGING, f"hydra.run.dir={tmp_path}/export"]
    assert entrypoints.run_in_process("diana_lab.export", args) == 0
    assert onnx.is_file() and onnx.with_suffix(".json").is_file()
    import mlflow

    mlflow.set_tracking_uri(trained.uri)
    graph = mlflow.pyfunc.load_model(f"runs:/{trained.run_id}/policy_onnx")
    example = {"goal": np.zeros((3, 7), np.float32), "depth_image": np.ones((3, 1, 12, 16), np.float32)}
    assert graph.predict(example)["offset"].shape == (3, 2)


@pytest.mark.parametrize(
    ("spec", "expect"),
    [
        ("models:/nope/1", ["policy=models:/nope/1", "no registered model 'nope'", NAME]),
        (f"models:/{NAME}/7", [f"policy=models:/{NAME}/7", "no version 7", "versions: 1"]),
        (f"models:/{NAME}@nope", ["no alias 'nope'", "aliases:"]),
        (f"models:/{NAME}", ["models:/<name>/<version>", "models:/<name>@<alias>"]),
        (f"models:/{NAME}/latest", ["models:/<name>/<version> (a number)"]),
    ],
)
def test_unknown_or_malformed_registered_versions_are_clear_errors(trained, spec, expect):
    with pytest.raises(UserError) as err:
        load_policy(spec, compose([f"tracking.uri={trained.uri}"]), EvalConfig())
    for text in expect:
        assert text in str(err.value)


def test_a_registry_uri_without_its_store_names_tracking_uri(tmp_path):
    with pytest.raises(UserError, match=r"tracking\.uri=.*has no store at"):
        load_policy(f"models:/{NAME}/1", compose([f"tracking.uri=sqlite:///{tmp_path}/none.db"]), EvalConfig())
    assert not (tmp_path / "none.db").exists()


@pytest.mark.parametrize("name", ["my/model", "a@b", "models:/x", " spaced", "-dash", "x" * 300])
def test_bad_register_model_names_are_refused_naming_the_key(name):
    with pytest.raises(ConfigError, match=r"tracking\.register_model"):
        to_object("tracking", {"register_model": name})


def test_register_model_needs_tracking():
    with pytest.raises(ConfigError, match=r"tracking.register_model=x.*tracking.enabled=false"):
        to_object("tracking", {"register_model": "x", "enabled": False})
    assert to_object("tracking", {"register_model": "rover_nav.v2-a"}).register_model == "rover_nav.v2-a"
    assert to_object("tracking", compose([]).tracking).register_model is None


def test_the_pyfunc_maps_a_continuous_policy_like_the_env_with_its_statistics(tmp_path):
    """A square action space, VecNormalize statistics far from (0, 1) and a clip that bites (the export tests'
    model): the pyfunc's offsets are the env's mapping of the SB3 model's actions on normalised observations."""
    from tests.deploy.helpers import make_run, run_config

    cfg = run_config()
    env = make_run(tmp_path / "run", cfg)
    try:
        folder = _policy_folder(tmp_path / "run", OmegaConf.to_yaml(cfg, resolve=True), None, tmp_path / "model")
        model = PolicyModel()
        model.load(folder)
        loaded = load_policy(str(tmp_path / "run"), cfg, EvalConfig())
        obs, _ = env.reset(seed=1)
        observations, yaws = [], []
        for _ in range(6):
            observations.append(obs)
            yaws.append(env.pose_estimate.yaw)
            obs, *_ = env.step(env.action_space.sample())
    finally:
        env.close()
    batch = {k: np.stack([o[k] for o in observations]) for k in observations[0]}
    out = model.predict(None, batch)
    mapping = WaypointMapping(to_object("action_space", cfg.action_space))
    actions = [loaded.policy.act(o, None) for o in observations]
    np.testing.assert_allclose(out["action"], np.stack(actions), atol=1e-6)
    np.testing.assert_allclose(out["local_offset"], [mapping.offset(a, 0.0) for a in actions], atol=1e-5)
    np.testing.assert_allclose(out["offset"], [mapping.offset(a, y) for a, y in zip(actions, yaws)], atol=1e-5)
    assert np.abs(out["local_offset"]).max() > 0.5  # actions away from 0: the mapping is exercised
    with pytest.raises(ValueError, match="missing observation keys"):
        model.predict(None, {"goal": batch["goal"]})


@pytest.mark.parametrize("setting", [None, "true"])
def test_the_users_own_artifact_bar_setting_is_restored(monkeypatch, setting):
    import os

    from diana_lab.tracking.logged_models import ARTIFACT_BARS, no_artifact_bars

    if setting is None:
        monkeypatch.delenv(ARTIFACT_BARS, raising=False)
    else:
        monkeypatch.setenv(ARTIFACT_BARS, setting)
    with no_artifact_bars():
        assert os.environ[ARTIFACT_BARS] == "false"
    assert os.environ.get(ARTIFACT_BARS) == setting
