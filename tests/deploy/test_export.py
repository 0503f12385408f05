"""``python -m diana_lab.export``: the graph's parts, the sidecar, and the mistakes it refuses."""

from __future__ import annotations

import json

import numpy as np
import onnxruntime as ort
import pytest
import torch
from torch import nn

from diana_lab.cli import UserError
from diana_lab.config import ConfigError, compose, to_object
from diana_lab.deploy import PolicySpec, sidecar_path
from diana_lab.deploy.export import (
    DEFAULT_OPSET,
    DYNAMO_MIN_OPSET,
    MatmulAdaptiveAvgPool2d,
    export_policy,
    square_to_disc,
)
from diana_lab.envs.action_spaces import WaypointMapping
from diana_lab.envs.action_spaces import square_to_disc as square_to_disc_np
from diana_lab.export import main
from tests.presets import CAMERA_SQUARE

from .conftest import export_run
from .helpers import run_config


@pytest.mark.parametrize(("in_hw", "out_hw"), [((14, 14), (3, 4)), ((6, 8), (3, 4)), ((5, 7), (5, 2))])
def test_matmul_pool_equals_adaptive_average_pool(in_hw, out_hw):
    x = torch.randn(2, 3, *in_hw)
    want = nn.AdaptiveAvgPool2d(out_hw)(x)
    torch.testing.assert_close(MatmulAdaptiveAvgPool2d(in_hw, out_hw)(x), want, rtol=1e-5, atol=1e-6)


def test_torch_disc_mapping_equals_the_envs():
    g = np.linspace(-1, 1, 41)
    a = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)  # includes 0, the axes and both diagonals
    got = square_to_disc(torch.as_tensor(a, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(got, square_to_disc_np(a), atol=1e-12)


def test_sidecar_describes_what_the_runtime_needs(depth_run):
    node = json.loads(sidecar_path(depth_run.onnx).read_text())
    cfg = compose([*CAMERA_SQUARE, "world=craters"])
    assert (
        node["sensor"].items()
        >= {
            "type": "depth_camera",
            "width": cfg.sensor.width,
            "height": cfg.sensor.height,
            "hfov_deg": cfg.sensor.hfov_deg,
            "mount_xyz": list(cfg.sensor.mount_xyz),
            "mount_pitch_deg": cfg.sensor.mount_pitch_deg,
            "min_range": cfg.sensor.min_range,
            "max_range": cfg.sensor.max_range,
        }.items()
    )
    assert node["encoding"] == {"name": "depth_image", "shape": [1, 48, 64], "params": {"no_return": 1.0}}
    assert node["action_space"]["shape"] == "square" and node["action_space"]["frame"] == "rover"
    assert node["distance_scale"] == cfg.episode.distance_scale
    assert node["inputs"] == {"goal": [-1, 7], "depth_image": [-1, 1, 48, 64]}
    assert node["normalization"] == {"baked_into_graph": True, "keys": ["goal"], "clip_obs": 2.0}
    assert node["source"]["config"] == "training" and node["source"]["algorithm"] == "PPO"
    assert node["diana_lab_version"] and node["source"]["export_check_max_error_m"] < 1e-4
    assert node["opset"] == DEFAULT_OPSET and node["source"]["exporter"] == "torchscript"  # dynamo needs opset 18
    spec = PolicySpec.load(sidecar_path(depth_run.onnx))
    assert PolicySpec.from_dict(json.loads(spec.to_json())) == spec  # the JSON round trip is lossless


def test_the_graph_takes_any_batch_and_maps_actions_like_the_env(depth_run):
    session = ort.InferenceSession(str(depth_run.onnx), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    goal = rng.uniform(-1, 1, (5, 7)).astype(np.float32)
    image = rng.uniform(0, 1, (5, 1, 48, 64)).astype(np.float32)
    offset, action = session.run(["offset", "action"], {"goal": goal, "depth_image": image})
    assert offset.shape == action.shape == (5, 2) and np.all(np.abs(action) <= 1)
    single = session.run(["offset"], {"goal": goal[2:3], "depth_image": image[2:3]})[0]
    np.testing.assert_allclose(single[0], offset[2], atol=1e-6)
    mapping = WaypointMapping(to_object("action_space", compose(CAMERA_SQUARE).action_space))
    np.testing.assert_allclose(offset, [mapping.offset(a, 0.0) for a in action], atol=1e-5)


def test_from_opset_18_the_dynamo_exporter_writes_one_file_that_drives_like_torch(depth_run, tmp_path):
    """``opset=18``: torch's current exporter (``dynamo=True``), weights inside the one graph file, batch dynamic,
    the same waypoints as the TorchScript graph and as the SB3 model (``model.predict`` through VecNormalize)."""
    import onnx

    out = tmp_path / "dynamo" / "policy.onnx"
    main.task(
        compose([f"policy={depth_run.run_dir}", f"output={out}", f"opset={DYNAMO_MIN_OPSET}"], config_name="export")
    )
    assert sorted(p.name for p in out.parent.iterdir()) == ["policy.json", "policy.onnx"]  # no external data
    spec = PolicySpec.load(sidecar_path(out))
    assert spec.opset == DYNAMO_MIN_OPSET and spec.source["exporter"] == "dynamo"
    assert spec.source["export_check_max_error_m"] < 1e-4
    graph = onnx.load(str(out))
    assert {o.domain: o.version for o in graph.opset_import}.get("") == DYNAMO_MIN_OPSET
    assert spec.inputs == {"goal": [-1, 7], "depth_image": [-1, 1, 48, 64]}
    rng = np.random.default_rng(1)
    goal = rng.uniform(-1, 1, (64, 7)).astype(np.float32)
    image = rng.uniform(0, 1, (64, 1, 48, 64)).astype(np.float32)
    feeds = {"goal": goal, "depth_image": image}
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    offset, action = session.run(["offset", "action"], feeds)
    assert offset.shape == action.shape == (64, 2)
    single = session.run(["offset"], {"goal": goal[5:6], "depth_image": image[5:6]})[0]
    np.testing.assert_allclose(single[0], offset[5], atol=1e-6)
    torchscript = ort.InferenceSession(str(depth_run.onnx), providers=["CPUExecutionProvider"])
    np.testing.assert_allclose(offset, torchscript.run(["offset"], feeds)[0], atol=1e-5)
    mapping, policy = depth_run.env.mapping, depth_run.loaded.policy
    want = [mapping.offset(policy.act({"goal": g, "depth_image": i}, depth_run.env), 0.0) for g, i in zip(goal, image)]
    np.testing.assert_allclose(offset, want, atol=1e-4)  # the parity tests' tolerance (m)


@pytest.fixture(scope="module")
def discrete_run(tmp_path_factory, small_world):
    """A tiny categorical policy over 8 headings x 2 distances in the world frame, exported by the CLI."""
    overrides = ["action_space=discrete", "action_space.headings=8", "action_space.distances=[1.5,3.0]"]
    run = export_run(
        tmp_path_factory.mktemp("discrete_run"), run_config(*overrides, "action_space.frame=world"), small_world
    )
    yield run
    run.env.close()


def test_a_discrete_policys_graph_gathers_the_argmax_candidate(discrete_run):
    node = json.loads(sidecar_path(discrete_run.onnx).read_text())
    assert node["action_space"] == {
        "shape": "discrete",
        "size": 7.0,
        "radius": 4.0,
        "frame": "world",
        "min_distance": 0.0,
        "headings": 8,
        "distances": [1.5, 3.0],
    }
    assert node["outputs"] == {"offset": [-1, 2], "action": [-1], "logits": [-1, 16]}
    assert node["shield"] is None and node["source"]["export_check_max_logit_error"] <= 1e-3
    spec = PolicySpec.load(sidecar_path(discrete_run.onnx))
    assert spec.action_space.distances == (1.5, 3.0) and spec.action_space.extent == 3.0
    assert PolicySpec.from_dict(json.loads(spec.to_json())) == spec
    session = ort.InferenceSession(str(discrete_run.onnx), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    goal = rng.uniform(-1, 1, (32, 7)).astype(np.float32)
    image = rng.uniform(0, 1, (32, 1, 48, 64)).astype(np.float32)
    offset, action, logits = session.run(["offset", "action", "logits"], {"goal": goal, "depth_image": image})
    assert action.shape == (32,) and action.dtype == np.int64 and len(set(action.tolist())) > 1
    np.testing.assert_array_equal(action, logits.argmax(axis=1))  # the choice is the logits' argmax
    mapping = discrete_run.env.mapping
    np.testing.assert_allclose(offset, mapping.candidates[action], atol=1e-6)
    # the graph's choice is the torch policy's deterministic action (model.predict, through VecNormalize)
    policy = discrete_run.loaded.policy
    for i in range(len(goal)):
        obs = {"goal": goal[i], "depth_image": image[i]}
        want = policy.act(obs, discrete_run.env)
        assert want.dtype == np.int64 and want.shape == () and int(want) == action[i]
        # and the graph ranks the candidates as torch does (what the slope shield walks through)
        ranking = policy.ranking(obs)
        np.testing.assert_array_equal(ranking[:8], np.argsort(-logits[i], kind="stable")[:8])


def test_export_refuses_an_action_space_the_policy_was_not_trained_with(depth_run, discrete_run, tmp_path):
    groups = compose(CAMERA_SQUARE)
    sensor, episode = to_object("sensor", groups.sensor), to_object("episode", groups.episode)
    square = to_object("action_space", groups.action_space)
    other = to_object("action_space", compose(["action_space=discrete"]).action_space)  # 48 candidates, not 16
    with pytest.raises(ConfigError, match=r"categorical policy over 16 candidates.*gives 48 candidates"):
        export_policy(discrete_run.loaded.model, None, sensor, other, episode, tmp_path / "p.onnx")
    with pytest.raises(ConfigError, match=r"over 16 candidates.*action_space\.shape=square"):
        export_policy(discrete_run.loaded.model, None, sensor, square, episode, tmp_path / "p.onnx")
    with pytest.raises(ConfigError, match=r"continuous \(2,\) action, but action_space\.shape=discrete"):
        export_policy(depth_run.loaded.model, None, sensor, other, episode, tmp_path / "p.onnx")
    assert not (tmp_path / "p.onnx").exists()


def test_export_refuses_baselines_missing_policies_and_other_sensors(depth_run, tmp_path):
    with pytest.raises(UserError, match="classical baseline"):
        main.task(compose(["policy=straight", f"output={tmp_path / 'p.onnx'}"], config_name="export"))
    with pytest.raises(UserError, match="policy: expected"):
        main.task(compose([f"output={tmp_path / 'p.onnx'}"], config_name="export"))
    model = depth_run.loaded.model
    sensor = to_object("sensor", compose([*CAMERA_SQUARE, "sensor.width=32"]).sensor)
    groups = compose(CAMERA_SQUARE)
    with pytest.raises(ConfigError, match=r"observes 'depth_image' \(1, 48, 64\).*\(1, 48, 32\)"):
        export_policy(
            model,
            None,
            sensor,
            to_object("action_space", groups.action_space),
            to_object("episode", groups.episode),
            tmp_path / "p.onnx",
        )
    assert not (tmp_path / "p.onnx").exists()


def test_a_sidecar_asking_for_the_shield_needs_a_discrete_graph_with_logits_and_valid_settings(discrete_run, depth_run):
    from dataclasses import asdict

    from diana_lab.config.evaluation import ShieldConfig
    from diana_lab.shield import ShieldSettings

    settings = asdict(ShieldSettings.from_config(ShieldConfig(enabled=True), to_object("robot", "jackal")))
    node = json.loads(sidecar_path(discrete_run.onnx).read_text())
    assert PolicySpec.from_dict({**node, "shield": settings}).shield == settings
    without_logits = {**node, "shield": settings, "outputs": {"offset": [-1, 2], "action": [-1]}}
    with pytest.raises(ValueError, match=r"shield: .*'logits'"):
        PolicySpec.from_dict(without_logits)
    with pytest.raises(ValueError, match=r"shield: .*half_track"):
        PolicySpec.from_dict({**node, "shield": {k: v for k, v in settings.items() if k != "half_track"}})
    # a bad value, not just a key
    with pytest.raises(ValueError, match=r"shield\.route_tolerance: expected a number >= 0, got -1"):
        PolicySpec.from_dict({**node, "shield": {**settings, "route_tolerance": -1.0}})
    continuous = json.loads(sidecar_path(depth_run.onnx).read_text())
    with pytest.raises(ValueError, match=r"shield: .*action_space.shape=square"):
        PolicySpec.from_dict({**continuous, "shield": settings})
