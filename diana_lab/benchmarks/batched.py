"""The batched simulator's figures: its step rate beside one ``RoverNavEnv``'s, training speed end to end
beside the old main command's, and memory per rover.

Each ratio is measured side by side in one process, repeats interleaved (hosts here swing up to 2x between runs):

* ``batched_env_steps_per_s``: waypoint steps per second of :class:`~diana_lab.envs.batched.BatchedRoverEnv`
  with the composed config's env groups (the main command's sensor and encoding) and ``train.n_envs`` rovers,
  random actions, resets included, one process on every core; ``batched_env_speedup`` is that over one
  ``RoverNavEnv`` of the same groups stepped the same way (one core, as an env is stepped).
* ``batched_env_steps_per_s_depth``: the same with the 64 x 48 depth camera and ``depth_image``.
* ``train_fps_ppo``: ``model.learn`` of the main command (the composed config, as the runner builds it, the
  phase threads and ``train.overlap`` included), a rollout and its update per repeat (with ``train.overlap``,
  :data:`OVERLAPPED_UPDATES`, since a ``learn`` call's first rollout is collected before its update);
  ``train_fps_speedup`` is that over :data:`ANCHOR`, the main command as it was before the batched env (kept
  fixed here).
* ``rss_mb_per_rover``: resident memory each rover adds to a batched env, in a fresh process.
"""

from __future__ import annotations

import gc
import multiprocessing
import time
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from diana_lab.benchmarks.core import BenchContext, Figure, Target, figure_from_samples, measurement, repeat
from diana_lab.benchmarks.envs import DEPTH, FORKSERVER_PRELOAD

__all__ = ["ANCHOR", "batched_env_steps", "rss_per_rover", "train_fps"]

# the main command before train.vec_env=batched (2026-12): 4 RoverNavEnvs one after another, the 64 x 48 depth
# camera, the square action space, the CNN, PPO's old settings and the reward of the time, which paid for stalls
ANCHOR = (
    "sensor=depth_camera",
    "sensor.encoding=depth_image",
    "action_space=square",
    "robot.tilt_guard_deg=null",
    "reward.terms.stall.weight=0.5",
)
ANCHOR_ALGO = {"n_steps": 256, "batch_size": 128, "n_epochs": 10, "learning_rate": 3e-4, "net_arch": [64, 64]}
ANCHOR_TRAIN = {"vec_env": "dummy", "n_envs": 4, "torch_threads": 1, "update_threads": 1}


def _actions(space: Any, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    if hasattr(space, "n"):
        return rng.integers(0, space.n, shape)
    return rng.uniform(-1.0, 1.0, (*shape, 2)).astype(np.float32)


@measurement("batched_env_steps_per_s", "batched_env_speedup", "batched_env_steps_per_s_depth")
def batched_env_steps(ctx: BenchContext) -> list[Figure]:
    from diana_lab import config as C
    from diana_lab.envs.batched import BatchedRoverEnv
    from diana_lab.training.envs import make_env, shared_world

    n = C.to_object("train", ctx.cfg.train).n_envs
    groups = ctx.env_groups("dynamics=kinematic")
    depth = ctx.env_groups("dynamics=kinematic", *DEPTH)
    batch_steps, single_steps = ctx.size(60, 10), ctx.size(1500, 250)
    rng = np.random.default_rng(ctx.seed)
    envs = {
        "batched": BatchedRoverEnv(groups, n, world_instances=[shared_world(groups["world"])]),
        "depth": BatchedRoverEnv(depth, n, world_instances=[shared_world(depth["world"])]),
    }
    single = make_env(groups)
    rates: dict[str, list[float]] = {"batched": [], "depth": [], "single": []}
    for env in envs.values():
        env.seed(ctx.seed)
        env.reset()
    single.reset(seed=ctx.seed)

    def sample() -> float:
        for name, env in envs.items():
            actions = _actions(env.action_space, rng, (batch_steps, n))
            t0 = time.perf_counter()
            for a in actions:
                env.step(a)
            rates[name].append(batch_steps * n / (time.perf_counter() - t0))
        actions = _actions(single.action_space, rng, (single_steps,))
        t0 = time.perf_counter()
        for a in actions:
            _, _, terminated, truncated, _ = single.step(a)
            if terminated or truncated:
                single.reset()
        rates["single"].append(single_steps / (time.perf_counter() - t0))
        return rates["batched"][-1] / rates["single"][-1]

    try:
        ratios = repeat(sample, ctx.repeats)
    finally:
        for env in envs.values():
            env.close()
        single.close()
    timed = slice(1, None)  # the first entry of each is the warm-up
    sensor = OmegaConf.select(ctx.cfg, "sensor.name")
    encoding = groups["sensor"].get("encoding")
    return [
        figure_from_samples(
            "batched_env_steps_per_s",
            "steps/s",
            rates["batched"][timed],
            batch=f"{batch_steps} steps of {n} rovers",
            note=f"BatchedRoverEnv, {sensor} ({encoding}), random actions, resets included, every core",
        ),
        figure_from_samples(
            "batched_env_speedup",
            "x",
            ratios,
            target=Target(">=", 8.0),
            batch=f"{batch_steps} steps of {n} rovers, then {single_steps} steps of one RoverNavEnv",
            note="batched_env_steps_per_s over one RoverNavEnv with the same sensor, interleaved repeats",
            extra={"single_env_steps_per_s": float(np.median(rates["single"][timed]))},
        ),
        figure_from_samples(
            "batched_env_steps_per_s_depth",
            "steps/s",
            rates["depth"][timed],
            batch=f"{batch_steps} steps of {n} rovers",
            note="BatchedRoverEnv, depth camera 64x48 (depth_image), random actions, resets included",
        ),
    ]


OVERLAPPED_UPDATES = 4  # per repeat with train.overlap: the first rollout of a learn() call is not overlapped


def _learner(cfg: Any, ctx: BenchContext) -> tuple[Any, Any, Any, int]:
    """The model, its env, its phase-threads callback and the steps of one repeat (one update; with
    ``train.overlap``, :data:`OVERLAPPED_UPDATES`), built as the runner does."""
    from diana_lab import config as C
    from diana_lab.agents.factory import build_model
    from diana_lab.training.envs import make_training_env, wrap_normalize
    from diana_lab.training.threads import check_overlap, phase_threads

    typed = C.validate(cfg, [g for g in ("action_space", "algo", "train") if g in cfg])
    algo, train = typed["algo"], typed["train"]
    if ctx.quick:
        algo.n_steps = max(8, algo.n_steps // 4)
        algo.batch_size = min(algo.batch_size, algo.n_steps * train.n_envs)
    check_overlap(train.overlap, algo.off_policy, algo.name)
    overlap = train.overlap
    venv = make_training_env(cfg, train, ctx.seed)
    if algo.normalize:
        venv = wrap_normalize(venv, algo, algo.gamma)
    model = build_model(algo, venv, ctx.seed, train.device, overlap=overlap)
    threads = phase_threads(train.torch_threads, train.update_threads, overlap)
    return model, venv, threads, train.n_envs * algo.n_steps * (OVERLAPPED_UPDATES if overlap else 1)


@measurement("train_fps_ppo", "train_fps_speedup")
def train_fps(ctx: BenchContext) -> list[Figure]:
    import torch

    main_cfg = ctx.cfg.copy()
    anchor_cfg = ctx.cfg.copy()
    pinned = {**{f"algo.{k}": v for k, v in ANCHOR_ALGO.items()}, **{f"train.{k}": v for k, v in ANCHOR_TRAIN.items()}}
    for key, value in pinned.items():
        OmegaConf.update(anchor_cfg, key, value)
    OmegaConf.update(anchor_cfg, "algo.extractor.elevation_encoder", "cnn")
    for group, values in ctx.env_groups(*ANCHOR).items():
        OmegaConf.update(anchor_cfg, group, values, merge=False)
    learners = {"main": _learner(main_cfg, ctx), "anchor": _learner(anchor_cfg, ctx)}
    rates: dict[str, list[float]] = {"main": [], "anchor": []}

    def sample() -> float:
        for name, (model, _, threads, per_update) in learners.items():
            t0 = time.perf_counter()
            model.learn(per_update, callback=threads, reset_num_timesteps=False, progress_bar=False)
            rates[name].append(per_update / (time.perf_counter() - t0))
        torch.set_num_threads(1)
        return rates["main"][-1] / rates["anchor"][-1]

    try:
        ratios = repeat(sample, ctx.repeats)
    finally:
        for _, venv, _, _ in learners.values():
            venv.close()
        torch.set_num_threads(1)
    timed = slice(1, None)
    main_model, main_venv, _, main_steps = learners["main"]
    train = OmegaConf.select(ctx.cfg, "train")
    return [
        figure_from_samples(
            "train_fps_ppo",
            "steps/s",
            rates["main"][timed],
            batch=f"{main_steps} steps ({train.n_envs} envs, {train.vec_env}) and their updates per repeat",
            note=f"SB3 PPO learn() of the main command's config (sensor {ctx.cfg.sensor.name}, "
            f"{ctx.cfg.algo.extractor.elevation_encoder} extractor, train.overlap={train.overlap}: with it, "
            f"{OVERLAPPED_UPDATES} updates a repeat, the first rollout not overlapped), phase threads as the runner "
            "sets them",
        ),
        figure_from_samples(
            "train_fps_speedup",
            "x",
            ratios,
            target=Target(">=", 15.0),
            batch="one update of each, interleaved",
            note="train_fps_ppo over the old main command (4 RoverNavEnvs in a DummyVecEnv, depth 64x48, CNN, "
            "PPO n_steps 256, batch 128, 10 epochs, 1 torch thread)",
            extra={"anchor_steps_per_s": float(np.median(rates["anchor"][timed]))},
        ),
    ]


def _rss_rovers(groups: dict[str, Any], seed: int, n: int) -> tuple[float, float]:
    """In a fresh process: RSS after a batched env of ``n`` rovers has stepped, then after one of ``3 n`` (MB)."""
    import psutil

    from diana_lab.envs.batched import BatchedRoverEnv
    from diana_lab.training.envs import shared_world

    proc = psutil.Process()
    world = shared_world(groups["world"])
    out = []
    keep = []
    for size in (n, 3 * n):
        env = BatchedRoverEnv(groups, size, world_instances=[world])
        env.seed(seed)
        env.reset()
        rng = np.random.default_rng(seed)
        for _ in range(5):
            env.step(_actions(env.action_space, rng, (size,)))
        keep.append(env)
        gc.collect()
        out.append(proc.memory_info().rss / 2**20)
    return out[0], out[1]


@measurement("rss_mb_per_rover")
def rss_per_rover(ctx: BenchContext) -> list[Figure]:
    """Resident memory each rover adds: the difference between batched envs of ``n`` and ``3 n`` rovers (one
    process, the world shared), over the ``2 n`` rovers between them."""
    from concurrent.futures import ProcessPoolExecutor

    n = ctx.size(32, 8)
    multiprocessing.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    samples = []
    groups = ctx.env_groups("dynamics=kinematic")
    context = multiprocessing.get_context("forkserver")
    with ProcessPoolExecutor(1, mp_context=context, max_tasks_per_child=1) as pool:  # a fresh process each
        for _ in range(min(ctx.repeats, 3)):
            small, large = pool.submit(_rss_rovers, groups, ctx.seed, n).result()
            samples.append((large - small) / (2 * n))
    return [
        figure_from_samples(
            "rss_mb_per_rover",
            "MB",
            samples,
            batch=f"batched envs of {n} and {3 * n} rovers",
            note="RSS growth per rover of BatchedRoverEnv (the main command's sensor), psutil",
        )
    ]
