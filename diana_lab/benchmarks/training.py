"""The DAgger expert's labelling cost (the training speed figures are in :mod:`diana_lab.benchmarks.batched`)."""

from __future__ import annotations

import time

from diana_lab.benchmarks.core import BenchContext, Figure, figure_from_samples, measurement, repeat

__all__ = ["expert_label_ms"]


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
