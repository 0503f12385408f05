"""Fixtures: one small cratered world, and a tiny depth-camera policy saved, loaded and exported once."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import torch

from diana_lab.config import build, compose, to_object
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.evaluation.loading import load_policy

from .helpers import EVAL, SMALL_WORLD, make_run, run_config


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """Two shared cores: torch's default of one thread per core only makes the tiny convolutions contend."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def small_world():
    return build(to_object("world", compose(SMALL_WORLD).world))


@dataclass
class ExportedRun:
    env: RoverNavEnv
    loaded: Any  # evaluation.loading.LoadedPolicy
    run_dir: Path
    onnx: Path


def export_run(
    run_dir: Path, cfg, world, normalize: bool = True, *evaluation: str, opset: int | None = None
) -> ExportedRun:
    """Save a tiny model of ``cfg`` as a run, export it through the CLI's task function, load it for torch;
    ``evaluation``: ``eval.*`` overrides of both (e.g. the slope shield's); ``opset``: the export's (which picks the
    exporter, :func:`diana_lab.deploy.export.exporter_for`), else its default."""
    from diana_lab.export import main

    env = make_run(run_dir, cfg, world, normalize)
    onnx = run_dir / "export" / "policy.onnx"
    chosen = [f"opset={opset}"] if opset is not None else []
    main.task(compose([f"policy={run_dir}", f"output={onnx}", *chosen, *evaluation], config_name="export"))
    eval_cfg = to_object("eval", compose(list(evaluation)).eval) if evaluation else EVAL
    return ExportedRun(env, load_policy(str(run_dir), cfg, eval_cfg), run_dir, onnx)


@pytest.fixture(scope="session")
def depth_run(tmp_path_factory, small_world):
    run = export_run(tmp_path_factory.mktemp("depth_run"), run_config(), small_world)
    yield run
    run.env.close()
