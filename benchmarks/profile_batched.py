"""Where a step of the batched env goes: cProfile of the main command's training env (the composed config).

    python benchmarks/profile_batched.py [--steps 60] [overrides ...]

Builds the vectorised env the runner builds (``make_training_env``), steps it with uniform random actions after a
warm-up of 10 steps (compilation), and prints the profile sorted by cumulative time.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np

from diana_lab.config import compose, to_object
from diana_lab.training.envs import make_training_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=60, help="profiled steps of the whole batch")
    parser.add_argument("--top", type=int, default=25, help="rows of the profile to print")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of conf/config.yaml")
    args = parser.parse_args()
    cfg = compose(args.overrides)
    venv = make_training_env(cfg, to_object("train", cfg.train), int(cfg.seed))
    rng = np.random.default_rng(int(cfg.seed))

    def actions() -> np.ndarray:
        space = venv.action_space
        if hasattr(space, "n"):
            return rng.integers(0, space.n, venv.num_envs)
        return rng.uniform(-1.0, 1.0, (venv.num_envs, *space.shape)).astype(np.float32)

    venv.reset()
    for _ in range(10):
        venv.step(actions())
    profiler = cProfile.Profile()
    t0 = time.perf_counter()
    profiler.enable()
    for _ in range(args.steps):
        venv.step(actions())
    profiler.disable()
    wall = time.perf_counter() - t0
    rate = args.steps * venv.num_envs / wall
    print(f"{args.steps} steps of {venv.num_envs} rovers in {wall:.2f} s: {rate:,.0f} steps/s")
    pstats.Stats(profiler).sort_stats("cumulative").print_stats(args.top)
    venv.close()


if __name__ == "__main__":
    main()
