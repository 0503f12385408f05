"""The same config and seed give the same evaluation of a trained policy, in two separate processes.

tests/evaluation covers the A* baseline; this covers a Stable-Baselines3 model (torch inference, the
observation pipeline it reads, and -- with ``eval.deterministic=false`` -- the seeding of its sampled
actions). Separate processes, so nothing can hide in a warm cache or a shared generator.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from .helpers import TINY_EVAL, run_cli, train_tiny_model


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return train_tiny_model(tmp_path_factory.mktemp("tiny_model"))


@pytest.mark.slow
@pytest.mark.parametrize("deterministic", ["true", "false"])
def test_a_trained_policy_evaluates_byte_identically_in_two_processes(
    tiny_model: Path, tmp_path: Path, deterministic: str
) -> None:
    args = [
        f"policy={tiny_model}",
        *TINY_EVAL,
        "eval.episodes=3",
        "eval.seed=99",
        f"eval.deterministic={deterministic}",
        "sensor.width=16",
        "sensor.height=12",
        "sensor.noise=realistic",  # the per-episode noise seeds must reproduce too
        "tracking.enabled=false",
    ]
    outputs = []
    for name in ("a", "b"):
        out = tmp_path / f"{name}.json"
        proc = run_cli("diana_lab.evaluate", [*args, f"output={out}", f"hydra.run.dir={tmp_path / name}"], tmp_path)
        assert proc.returncode == 0, proc.stderr
        outputs.append((out.read_bytes(), (tmp_path / name / "episodes.csv").read_bytes()))
    assert outputs[0] == outputs[1]
    assert b'"episodes": 3' in outputs[0][0]
