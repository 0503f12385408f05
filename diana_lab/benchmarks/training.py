"""Training throughput: SB3 PPO steps per second, updates included, built exactly as the runner builds it.

The model comes from :func:`diana_lab.agents.factory.build_model` on the vectorised env of
:func:`diana_lab.training.envs.make_training_env` (``train.n_envs`` envs, ``train.vec_env``, VecNormalize when
``algo.normalize``), so this is the speed of ``python -m diana_lab algo=ppo`` without tracking, checkpoints
and evaluations. One repeat is one rollout plus its update (``n_envs x n_steps`` steps); the quick mode
shortens the rollout (``algo.n_steps=32``), which keeps the update cost per step the same (PPO makes
``n_epochs x n_envs x n_steps / batch_size`` minibatch steps per update).
"""

from __future__ import annotations

import time
from typing import Any

from omegaconf import OmegaConf

from diana_lab.benchmarks.core import BenchContext, Figure, figure_from_samples, measurement, repeat
from diana_lab.benchmarks.envs import DEPTH

__all__ = ["expert_label_ms", "ppo_config", "train_fps_ppo"]

QUICK_N_STEPS = 32


def ppo_config(ctx: BenchContext) -> Any:
    """The composed ``algo`` when it is PPO (so ``algo.*`` overrides apply), else ``conf/algo/ppo.yaml``."""
    from diana_lab import config as C

    algo_node = ctx.cfg.algo if ctx.cfg.algo.get("name") == "ppo" else C.compose([], "algo/ppo").algo
    return C.to_object("algo", algo_node)


@measurement("train_fps_ppo")
def train_fps_ppo(ctx: BenchContext) -> list[Figure]:
    from diana_lab import config as C
    from diana_lab.agents.factory import build_model
    from diana_lab.training.envs import make_training_env, wrap_normalize

    algo = ppo_config(ctx)
    if ctx.quick:
        algo.n_steps = QUICK_N_STEPS
    train = C.to_object("train", ctx.cfg.train)
    env_cfg = OmegaConf.create(ctx.env_groups("dynamics=kinematic", *DEPTH))
    venv = make_training_env(env_cfg, train, ctx.seed)
    if algo.normalize:
        venv = wrap_normalize(venv, algo, algo.gamma)
    model = build_model(algo, venv, ctx.seed, train.device)
    per_update = train.n_envs * algo.n_steps

    def sample() -> float:
        t0 = time.perf_counter()
        model.learn(per_update, reset_num_timesteps=False, progress_bar=False)
        return per_update / (time.perf_counter() - t0)

    try:
        samples = repeat(sample, ctx.repeats)
    finally:
        venv.close()
    minibatches = algo.n_epochs * -(-per_update // algo.batch_size)
    return [
        figure_from_samples(
            "train_fps_ppo",
            "steps/s",
            samples,
            batch=f"1 update: {train.n_envs} envs ({train.vec_env}) x {algo.n_steps} steps + {minibatches} minibatches",
            note=f"SB3 PPO learn(), kinematic, depth 64x48, batch {algo.batch_size}, {algo.n_epochs} epochs, "
            f"torch 1 thread, {train.device}",
        )
    ]


@measurement("expert_label_ms")
def expert_label_ms(ctx: BenchContext) -> list[Figure]:
    """The reference recipe's DAgger expert (``train.imitation.expert`` of ``+experiment=reference``) labelling
    the states of its own env: ms per label, the expert driving (its every step a fresh search)."""
    from diana_lab import config as C
    from diana_lab.training.envs import env_config, make_env
    from diana_lab.training.imitation import make_expert

    cfg = C.compose(["+experiment=reference"], config_name="config")
    imitation = C.to_object("train", cfg.train).imitation
    env = make_env(env_config(cfg))
    expert = make_expert(imitation)
    steps = ctx.size(120, 30)
    obs, _ = env.reset(seed=ctx.seed)
    expert.reset(env)

    def sample() -> float:
        nonlocal obs
        spent = 0.0
        for _ in range(steps):
            t0 = time.perf_counter()
            action = expert.act(obs, env)
            spent += time.perf_counter() - t0
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                obs, _ = env.reset()
                expert.reset(env)
        return 1e3 * spent / steps

    try:
        samples = repeat(sample, ctx.repeats)
    finally:
        env.close()
    return [
        figure_from_samples(
            "expert_label_ms",
            "ms",
            samples,
            batch=f"{steps} labels",
            note=f"{imitation.expert} on +experiment=reference's env (mars_yard, lidar map with memory), "
            "expert.act per step, resets excluded, 1 thread",
        )
    ]
