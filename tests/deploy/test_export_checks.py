"""What ``python -m diana_lab.export`` takes from the training config, and what it refuses before writing.

A tiny discrete policy is saved as a run trained behind the slope shield (with a non-default ``top_k``, tilt limit
and ``distance_scale``, so that the training's values can be told from the command line's). Exports go through
:func:`diana_lab.deploy.command.run` with the overrides Hydra would hand it (as ``main`` does), or through
``main.task`` with a composed config, which shows only the settings that differ from the defaults.
"""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from diana_lab.cli import UserError
from diana_lab.config import compose, to_object
from diana_lab.deploy.command import PRETRAINED_PRESET, chosen_keys, export_shield, run
from diana_lab.deploy.export import DEFAULT_OPSET, DYNAMO_MIN_OPSET, check_opset, exporter_for, opset_range
from diana_lab.deploy.spec import PolicySpec, sidecar_path
from diana_lab.evaluation.loading import PRETRAINED_DIR

from .helpers import make_run, run_config

TRAINING = [
    "action_space=discrete",
    "action_space.headings=8",
    "action_space.distances=[1,2]",
    "episode.distance_scale=40",
    "eval.shield.enabled=true",
    "eval.shield.top_k=4",
    "eval.shield.limit_deg=20",
]


@pytest.fixture(scope="module")
def shielded_run(tmp_path_factory, small_world):
    run_dir = tmp_path_factory.mktemp("shielded_run")
    make_run(run_dir, run_config(*TRAINING), small_world).close()
    return run_dir


def export(run_dir, output, *args: str):
    """Export as the command line ``policy=<run_dir> output=<output> *args`` does."""
    overrides = [f"policy={run_dir}", f"output={output}", *args]
    return run(compose(overrides, config_name="export"), overrides)


def test_the_training_configs_shield_goes_into_the_sidecar_unless_the_command_line_sets_it(
    shielded_run, tmp_path, capsys
):
    from diana_lab.export import main

    onnx = tmp_path / "a" / "policy.onnx"
    main.task(compose([f"policy={shielded_run}", f"output={onnx}"], config_name="export"))
    spec = PolicySpec.load(sidecar_path(onnx))
    assert spec.shield is not None and (spec.shield["top_k"], spec.shield["limit_deg"]) == (4, 20.0)
    assert "eval.shield: on as in policy" in capsys.readouterr().out  # said, not silent
    # the command line's settings are laid over the training's: an explicit default too
    off = export(shielded_run, tmp_path / "b" / "policy.onnx", "eval.shield.enabled=false")
    assert off.shield is None
    top_k = export(shielded_run, tmp_path / "c" / "policy.onnx", "eval.shield.top_k=8")
    assert top_k.shield is not None and (top_k.shield["top_k"], top_k.shield["limit_deg"]) == (8, 20.0)
    assert "with eval.shield.top_k from the command line" in capsys.readouterr().out


def test_the_shipped_policy_exports_behind_its_presets_shield():
    """Its config predates ``eval.shield``; the preset it is reported with holds the shield."""
    train = OmegaConf.load(PRETRAINED_DIR / "config.yaml")
    assert OmegaConf.select(train, "eval.shield", default=None) is None
    preset = to_object("eval", compose([PRETRAINED_PRESET]).eval).shield
    assert preset.enabled
    for args in (["policy=pretrained"], ["policy=pretrained", PRETRAINED_PRESET]):
        cfg = compose(args, config_name="export")
        shield, note = export_shield(cfg, train, chosen_keys(cfg, args), "pretrained")
        assert shield == preset
        assert (PRETRAINED_PRESET in note) == (len(args) == 1)  # said when the command line did not give it
    args = ["policy=pretrained", "eval.shield.enabled=false"]
    cfg = compose(args, config_name="export")
    assert not export_shield(cfg, train, chosen_keys(cfg, args), "pretrained")[0].enabled


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["action_space.distances=[1,3]"], r"action_space\.distances=\[1\.0, 3\.0\] \(training \[1\.0, 2\.0\]\)"),
        (["robot=husky"], r"robot=husky \(training jackal\)"),  # the shield's size
        # the default value, chosen explicitly: only the command line's overrides tell it from a default
        (["episode.distance_scale=50"], r"episode\.distance_scale=50\.0 \(training 40\.0\)"),
        (["sensor=depth_camera", "sensor.width=32"], r"sensor\.width=32 \(training 64\)"),
    ],
)
def test_command_line_settings_that_would_change_the_exported_files_are_refused(shielded_run, tmp_path, args, message):
    onnx = tmp_path / "policy.onnx"
    with pytest.raises(UserError, match=rf"^{message}: .*training config.*drop them"):
        export(shielded_run, onnx, *args)
    assert not onnx.exists()


def test_command_line_settings_that_do_not_reach_the_exported_files_are_named(shielded_run, tmp_path, capsys):
    spec = export(shielded_run, tmp_path / "policy.onnx", "sensor.noise_level=2", "robot.tilt_guard_deg=30")
    assert spec.action_space.distances == (1.0, 2.0) and spec.distance_scale == 40.0
    out = capsys.readouterr().out
    assert "note: not in the exported files" in out
    assert "sensor.noise_level=2" in out and "robot.tilt_guard_deg=30" in out


def test_an_output_that_would_be_its_own_sidecar_is_refused(shielded_run, tmp_path):
    for name in ("policy.json", "policy.JSON"):
        with pytest.raises(UserError, match=rf"^output=.*{name}: the sidecar .*expected the graph's path"):
            export(shielded_run, tmp_path / name)
        assert not (tmp_path / name).exists()


def test_opsets_outside_the_exporters_range_are_refused_before_anything_is_written(shielded_run, tmp_path):
    import onnx
    from torch.onnx import _constants

    low, high = opset_range()
    assert low == _constants.ONNX_MIN_OPSET and low <= DEFAULT_OPSET <= high <= onnx.defs.onnx_opset_version()
    # the TorchScript exporter up to 17 (the default: TensorRT 8.6), the dynamo one from 18 to torch's most
    assert low < DYNAMO_MIN_OPSET <= high and DEFAULT_OPSET < DYNAMO_MIN_OPSET
    assert [exporter_for(o) for o in (low, DEFAULT_OPSET, DYNAMO_MIN_OPSET, high)] == [
        "torchscript",
        "torchscript",
        "dynamo",
        "dynamo",
    ]
    check_opset(low), check_opset(high)
    for opset in (5, low - 1, high + 1, 99):
        with pytest.raises(UserError, match=rf"^opset={opset}: expected an ONNX opset from {low} to {high}"):
            check_opset(opset)
    onnx_path = tmp_path / "policy.onnx"
    with pytest.raises(UserError, match=r"^opset=5: "):
        export(shielded_run, onnx_path, "opset=5")
    assert not onnx_path.exists() and not sidecar_path(onnx_path).exists()


def test_an_export_that_fails_after_writing_the_graph_leaves_nothing_behind(shielded_run, tmp_path, monkeypatch):
    import onnx

    def refuse(path, *args, **kwargs):
        raise onnx.checker.ValidationError("Bad node spec for node /Cast")

    monkeypatch.setattr(onnx.checker, "check_model", refuse)
    onnx_path = tmp_path / "policy.onnx"
    with pytest.raises(UserError, match=r"^opset=16: .*Bad node spec.*nothing was written"):
        export(shielded_run, onnx_path, "opset=16")
    assert not onnx_path.exists() and not sidecar_path(onnx_path).exists()
    with pytest.raises(onnx.checker.ValidationError):  # at the tested opset: a bug, with its own traceback
        export(shielded_run, onnx_path)
    assert not onnx_path.exists()


def test_the_shield_can_be_turned_on_for_a_policy_trained_without_it(tmp_path_factory, small_world, tmp_path):
    """Through the command line's up-front checks: they used to refuse ``eval.shield.enabled=true`` over the
    command line's (continuous, default) action space, which the export does not use: it takes the training's."""
    import subprocess
    import sys

    run_dir = tmp_path_factory.mktemp("unshielded_run")
    make_run(run_dir, run_config(*(a for a in TRAINING if not a.startswith("eval.shield"))), small_world).close()
    onnx = tmp_path / "policy.onnx"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "diana_lab.export",
            f"policy={run_dir}",
            f"output={onnx}",
            "eval.shield.enabled=true",
            f"hydra.run.dir={tmp_path / 'hydra'}",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    spec = PolicySpec.load(sidecar_path(onnx))
    assert spec.shield is not None and spec.action_space.shape == "discrete"
