"""``python -m diana_lab.bench [quick=true] [output=results.json] [only=[key,...]] [profile=true]``

Measures every speed figure of the platform in one process (sensors against PyBullet's ray test and
TinyRenderer, the dynamics, env steps, vectorised scaling, PPO training, memory), prints a table and writes
the JSON documented in ``benchmarks/README.md``::

    python -m diana_lab.bench output=benchmarks/latest.json              # full, a few minutes
    python -m diana_lab.bench quick=true output=benchmarks/latest_quick.json   # under a minute
    python -m diana_lab.bench 'only=[sensor_ms,kinematic_waypoints_per_s]' repeats=3
    python -m diana_lab.bench 'only=[profile]'      # cProfile of env.step -> benchmarks/profile_env_step.txt

Exit status 1 when a measurement failed (its keys are null in the JSON, with the error).
"""

from __future__ import annotations

import os
import sys

# before open3d and torch load (lazily, in the measurements): single-core figures mean one OpenMP thread
# too, and SubprocVecEnv workers inherit it
os.environ.setdefault("OMP_NUM_THREADS", "1")

from omegaconf import DictConfig

from diana_lab.cli import hydra_app


@hydra_app(config_name="bench")
def main(cfg: DictConfig) -> None:
    from diana_lab.benchmarks import run

    command = " ".join(["python -m diana_lab.bench", *sys.argv[1:]])
    result = run(cfg, command=command)
    if result["errors"]:
        print(f"error: measurements failed: {', '.join(sorted(result['errors']))}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
