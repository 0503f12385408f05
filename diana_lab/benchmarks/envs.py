"""Env figures: full ``env.step`` throughput, SubprocVecEnv scaling, and resident memory per env.

The envs are built by the training code's own factories (:func:`diana_lab.training.envs.make_env` and
:func:`~diana_lab.training.envs.make_training_env`), so these are the envs training steps: Monitor wrappers,
the per-process shared world, and resets at episode ends all included. Actions are uniform random in
[-1, 1]^2 from a seeded generator (drawn before the timed loop), for the square action space (:data:`SCALAR_ENV`).
"""

from __future__ import annotations

import gc
import multiprocessing
import time
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from diana_lab.benchmarks.core import BenchContext, Figure, Target, figure_from_samples, measurement, repeat

__all__ = ["env_steps_kinematic", "env_steps_physics", "rss_per_env", "vec_env_scaling"]

DEPTH = ("sensor=depth_camera", "sensor.encoding=depth_image")
# the single env's figures: the 64 x 48 depth camera and the square action space, which the random actions fit,
# whatever the main command's defaults (their history and DIANA-Gym's anchor are of this set-up)
SCALAR_ENV = (*DEPTH, "action_space=square")
FORKSERVER_PRELOAD = ("diana_lab.training.envs", "diana_lab.sensing", "diana_lab.sim.kinematic", "diana_lab.planning")
DIANA_GYM_ANCHOR = {"name": "DIANA-Gym (Gazebo + ROS 2 at real time), at most", "value": 6.7}


def _groups(ctx: BenchContext, dynamics: str) -> dict[str, Any]:
    return ctx.env_groups(f"dynamics={dynamics}", *SCALAR_ENV)


def _env_steps(ctx: BenchContext, key: str, dynamics: str, steps: int, target: Target) -> Figure:
    from diana_lab.training.envs import make_env

    env = make_env(_groups(ctx, dynamics))
    rng = np.random.default_rng(ctx.seed)
    env.reset(seed=ctx.seed)
    episodes: list[int] = []

    def sample() -> float:
        actions = rng.uniform(-1.0, 1.0, (steps, 2)).astype(np.float32)
        ends = 0
        t0 = time.perf_counter()
        for a in actions:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()
                ends += 1
        wall = time.perf_counter() - t0
        episodes.append(ends)
        return steps / wall

    try:
        samples = repeat(sample, ctx.repeats)
    finally:
        env.close()
    fig = figure_from_samples(
        key,
        "steps/s",
        samples,
        batch=f"{steps} steps",
        target=target,
        note=f"env.step, random actions, {dynamics}, depth 64x48, resets included, 1 core",
        extra={"episodes_per_batch": float(np.mean(episodes))},
    )
    if fig.value is not None:
        fig.anchor = {**DIANA_GYM_ANCHOR, "ratio": fig.value / DIANA_GYM_ANCHOR["value"]}
    return fig


@measurement("env_steps_per_s_kinematic")
def env_steps_kinematic(ctx: BenchContext) -> list[Figure]:
    steps = ctx.size(1500, 250)
    return [_env_steps(ctx, "env_steps_per_s_kinematic", "kinematic", steps, Target(">=", 1000.0))]


@measurement("env_steps_per_s_physics")
def env_steps_physics(ctx: BenchContext) -> list[Figure]:
    steps = ctx.size(40, 8)
    return [_env_steps(ctx, "env_steps_per_s_physics", "physics", steps, Target(">=", 20.0))]


@measurement("vec_env_scaling_2")
def vec_env_scaling(ctx: BenchContext) -> list[Figure]:
    """Env steps/s of 2 SubprocVecEnv workers over 1 worker (same IPC path; ideal 2.0 on 2 free cores)."""
    from diana_lab.config.run import TrainConfig
    from diana_lab.training.envs import make_training_env

    # Workers start from a forkserver that has imported the env stack once (not measured, only quicker:
    # without it each worker imports torch and SB3 afresh, ~3 s apiece on a loaded 2-core machine)
    multiprocessing.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    cfg = OmegaConf.create(_groups(ctx, "kinematic"))
    steps = ctx.size(1200, 200)  # env steps per repeat for each of the two set-ups
    venvs: dict[int, Any] = {}
    rng = np.random.default_rng(ctx.seed)
    rates: dict[int, list[float]] = {1: [], 2: []}

    def sample() -> float:
        for n, venv in venvs.items():
            actions = rng.uniform(-1.0, 1.0, (steps // n, n, 2)).astype(np.float32)
            t0 = time.perf_counter()
            for a in actions:
                venv.step(a)
            rates[n].append(steps / (time.perf_counter() - t0))
        return rates[2][-1] / rates[1][-1]

    try:
        for n in (1, 2):
            venvs[n] = make_training_env(cfg, TrainConfig(n_envs=n, vec_env="subproc"), ctx.seed)
            venvs[n].reset()
        samples = repeat(sample, ctx.repeats)
    finally:
        for venv in venvs.values():
            venv.close()
    timed = slice(1, None)  # the first entry is the warm-up
    return [
        figure_from_samples(
            "vec_env_scaling_2",
            "x",
            samples,
            batch=f"{steps} env steps with 1 and with 2 workers",
            note="steps/s of SubprocVecEnv(2) / SubprocVecEnv(1), kinematic, depth 64x48 (ideal 2.0)",
            extra={
                "steps_per_s_1": float(np.median(rates[1][timed])),
                "steps_per_s_2": float(np.median(rates[2][timed])),
            },
        )
    ]


def _rss_samples(groups: dict[str, Any], seed: int, per: int, batches: int) -> tuple[list[float], float]:
    """In a fresh process: one env, then ``batches`` batches of ``per`` more; MB of RSS per env per batch.

    A fresh process, because in the benchmark's own process the envs would first fill the heap that
    earlier measurements freed, and RSS would barely move (glibc keeps freed memory for reuse).
    """
    import psutil

    from diana_lab.training.envs import make_env

    proc = psutil.Process()
    envs = [make_env(groups)]
    envs[0].reset(seed=seed)
    out = []
    for _ in range(batches):
        gc.collect()
        before = proc.memory_info().rss
        for _ in range(per):
            env = make_env(groups)
            env.reset(seed=seed + len(envs))
            env.step(np.zeros(2, dtype=np.float32))  # touch the step path's buffers too
            envs.append(env)
        gc.collect()
        out.append((proc.memory_info().rss - before) / per / 2**20)
    total = proc.memory_info().rss / 2**20
    for env in envs:
        env.close()
    return out, total


@measurement("rss_mb_per_env")
def rss_per_env(ctx: BenchContext) -> list[Figure]:
    """Resident memory each additional env adds to one process (the world is shared, as in training)."""
    from concurrent.futures import ProcessPoolExecutor

    per = ctx.size(6, 3)
    repeats = min(ctx.repeats, 5)
    multiprocessing.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("forkserver")) as pool:
        batches, total = pool.submit(_rss_samples, _groups(ctx, "kinematic"), ctx.seed, per, 1 + repeats).result()
    return [
        figure_from_samples(
            "rss_mb_per_env",
            "MB",
            batches[1:],  # the first batch is the warm-up
            batch=f"{per} more envs",
            note="RSS growth per additional kinematic env (depth 64x48) in a fresh process, psutil",
            extra={"rss_mb_process": total, "envs_in_process": 1 + per * (1 + repeats)},
        )
    ]
