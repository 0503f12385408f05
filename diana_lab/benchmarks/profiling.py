"""A cProfile of ``env.step`` (kinematic, depth 64x48, random actions): where a training step's time goes.

Only the ``env.step`` calls are profiled (resets are not), and the report lists the top functions by
cumulative time and by own time. cProfile's per-call overhead inflates small Python functions relative to
C calls (open3d's cast, numpy), so read it for *where*, and the timed figures for *how much*.
"""

from __future__ import annotations

import cProfile
import io
import pstats
from pathlib import Path

import numpy as np

from diana_lab.benchmarks.core import BenchContext
from diana_lab.benchmarks.envs import SCALAR_ENV

__all__ = ["profile_env_step"]

TOP = 25


def profile_env_step(ctx: BenchContext, output: Path | None) -> str:
    """Profile ``ctx.size(3000, 500)`` kinematic steps; write the report to ``output`` (if given) and return it."""
    from diana_lab.training.envs import make_env

    steps = ctx.size(3000, 500)
    env = make_env(ctx.env_groups("dynamics=kinematic", *SCALAR_ENV))
    rng = np.random.default_rng(ctx.seed)
    env.reset(seed=ctx.seed)
    for a in rng.uniform(-1.0, 1.0, (50, 2)).astype(np.float32):  # warm-up: lazy scene, caches
        if any(env.step(a)[2:4]):
            env.reset()
    profiler = cProfile.Profile()
    try:
        for a in rng.uniform(-1.0, 1.0, (steps, 2)).astype(np.float32):
            profiler.enable()
            _, _, terminated, truncated, _ = env.step(a)
            profiler.disable()
            if terminated or truncated:
                env.reset()
    finally:
        env.close()
    buf = io.StringIO()
    buf.write(f"cProfile of {steps} env.step calls (kinematic, depth 64x48, random actions, resets excluded)\n")
    stats = pstats.Stats(profiler, stream=buf)
    stats.strip_dirs().sort_stats("cumulative").print_stats(TOP)
    buf.write(f"\n--- top {TOP} by own time (tottime) ---\n")
    stats.sort_stats("tottime").print_stats(TOP)
    text = buf.getvalue()
    if output is not None:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(text)
    return text
