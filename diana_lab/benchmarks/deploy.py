"""Deployment figures: the onboard policy's per-call latency in the ONNX runtime (:mod:`diana_lab.deploy`).

The policy is the shipped reference policy (``policy=pretrained``, the one issue 10's target names) with the
sensor and encoding it was trained on; without it (a fresh checkout before one is trained), a PPO policy of
the configured architecture on the kinematic depth-camera env (untrained: latency does not depend on the
weights). Either is exported by :func:`diana_lab.deploy.export.export_policy` to a temporary ``policy.onnx``
and loaded by :class:`diana_lab.deploy.Navigator` on one onnxruntime thread; the note says which it was.
Each repeat is one :func:`diana_lab.deploy.measure_latency` run (``Navigator.next_waypoint``: goal vector and
encoding of a synthetic flat-ground cloud, then inference); the figures are the medians over the repeats of
each run's p50 and p99 of the per-call times (p99 is a tail of single calls, not of batch averages).
Targets (from :mod:`diana_lab.deploy.latency`): <= 1 ms median and <= 2 ms p99 for the default depth camera.

Without ``diana_lab.deploy`` or onnxruntime both keys are null with a note saying so.
"""

from __future__ import annotations

import importlib.util
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from diana_lab.benchmarks.core import BenchContext, Figure, Target, figure_from_samples, measurement, repeat
from diana_lab.benchmarks.envs import DEPTH
from diana_lab.benchmarks.training import ppo_config

__all__ = ["policy_latency"]

KEYS = ("policy_latency_ms_p50", "policy_latency_ms_p99")
TARGETS = {"policy_latency_ms_p50": Target("<=", 1.0), "policy_latency_ms_p99": Target("<=", 2.0)}
MISSING_NOTE = "not measured: the deployment runtime (diana_lab.deploy, onnxruntime) is not installed"


def _reference_navigator(folder: Path) -> Any:
    """Export the shipped reference policy and load it as the rover would (None when it is not shipped)."""
    from diana_lab.config import compose, to_object
    from diana_lab.deploy import Navigator
    from diana_lab.deploy.export import export_policy
    from diana_lab.evaluation.loading import PRETRAINED_DIR, load_policy

    if not (PRETRAINED_DIR / "model.zip").is_file():
        return None
    cfg = compose([])
    loaded = load_policy("pretrained", cfg, to_object("eval", cfg.eval))
    train = loaded.train_cfg
    path = folder / "policy.onnx"
    export_policy(
        loaded.model,
        loaded.policy.vecnormalize,
        to_object("sensor", train.sensor),
        to_object("action_space", train.action_space),
        to_object("episode", train.episode),
        path,
        source={"label": "benchmark (shipped reference policy)"},
    )
    return Navigator.from_files(path, threads=1)


def _navigator(ctx: BenchContext, folder: Path) -> Any:
    """Export an untrained PPO policy of the configured architecture and load it as the rover would."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from diana_lab.agents.factory import build_model
    from diana_lab.deploy import Navigator
    from diana_lab.deploy.export import export_policy
    from diana_lab.training.envs import make_env

    groups = ctx.env_groups("dynamics=kinematic", *DEPTH)
    venv = DummyVecEnv([lambda: make_env(groups)])
    try:
        model = build_model(ppo_config(ctx), venv, ctx.seed, "cpu")
        path = folder / "policy.onnx"
        export_policy(
            model,
            None,
            ctx.typed("sensor", *DEPTH),
            ctx.typed("action_space"),
            ctx.typed("episode"),
            path,
            source={"label": "benchmark (untrained PPO)"},
        )
    finally:
        venv.close()
    return Navigator.from_files(path, threads=1)


@measurement(*KEYS)
def policy_latency(ctx: BenchContext) -> list[Figure]:
    if importlib.util.find_spec("diana_lab.deploy") is None or importlib.util.find_spec("onnxruntime") is None:
        return [Figure(key, "ms", None, note=MISSING_NOTE) for key in KEYS]
    from diana_lab.deploy import measure_latency

    calls = ctx.size(2000, 300)
    with tempfile.TemporaryDirectory(prefix="diana_bench_") as folder:
        nav = _reference_navigator(Path(folder))
        which = "the shipped reference policy" if nav is not None else "an untrained PPO of the configured architecture"
        if nav is None:
            nav = _navigator(ctx, Path(folder))
        runs = repeat(lambda: measure_latency(nav, n=calls, warmup=0), ctx.repeats)
    split = {
        "encode_p50_ms": float(np.median([r["encode_p50"] for r in runs])),
        "infer_p50_ms": float(np.median([r["infer_p50"] for r in runs])),
    }
    spec = nav.spec
    note = (
        f"Navigator.next_waypoint (goal + {spec.encoding.name} encoding of a {spec.sensor.type} cloud + ONNX "
        f"inference), onnxruntime 1 thread, {which}, synthetic flat-ground cloud"
    )
    return [
        figure_from_samples(
            key,
            "ms",
            [r[stat] for r in runs],
            batch=f"{calls} calls (statistic {stat} of the calls)",
            target=TARGETS[key],
            note=note,
            extra=split,
        )
        for key, stat in zip(KEYS, ("p50", "p99"))
    ]
