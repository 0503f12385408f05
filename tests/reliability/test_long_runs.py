"""Long runs leak nothing: resident memory, file descriptors, PyBullet clients, worker processes.

The long ones are ``slow`` (``./dev test-slow``; run with ``-s`` to see the figures they print). To keep
100,000 steps to minutes they use ``world=flat`` and a 16 x 12 camera: the loop, the episode sampler, the
reward and the ray caster run exactly as in training, only the rays are fewer. A shorter run with the
default 64 x 48 camera on the Mars yard covers the full-size sensor and terrain. Memory is measured after a
warm-up (allocator pools, caches and lazily built structures fill up in the first episodes), and the bound
(50 MB) is far above the noise of the allocator and far below what a per-step or per-episode leak of any
real size would add over 100,000 steps or 10,000 episodes.
"""

from __future__ import annotations

import functools
import gc
import math
import time

import numpy as np
import psutil
import pybullet as pb
import pytest

from diana_lab.config import compose
from diana_lab.envs.rover_nav import RoverNavEnv
from tests.presets import CAMERA_SQUARE

MB = 1024 * 1024
MAX_GROWTH = 50 * MB
FLAT_TINY = [*CAMERA_SQUARE, "world=flat", "sensor.width=16", "sensor.height=12", "episode.max_steps=10"]


def resources() -> tuple[int, int, int]:
    """(resident bytes, open file descriptors, threads) of this process, after a garbage collection."""
    gc.collect()
    me = psutil.Process()
    return me.memory_info().rss, me.num_fds(), me.num_threads()


def pybullet_clients() -> list[int]:
    """Ids of the PyBullet clients this process has connected (the ids are reused once freed)."""
    return [i for i in range(64) if pb.getConnectionInfo(i)["isConnected"]]


def drive(env: RoverNavEnv, steps: int, seed: int) -> tuple[int, int]:
    """``steps`` random actions, resetting whenever an episode ends; returns (steps, resets)."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    resets = 1
    for _ in range(steps):
        _, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        assert math.isfinite(reward)
        if terminated or truncated:
            env.reset()
            resets += 1
    return steps, resets


def check_no_growth(label: str, run: functools.partial, warmup: functools.partial) -> None:
    warmup()
    rss0, fds0, threads0 = resources()
    t0 = time.perf_counter()
    steps, resets = run()
    rss1, fds1, threads1 = resources()
    print(
        f"\n{label}: {steps} steps, {resets} resets in {time.perf_counter() - t0:.0f} s; "
        f"RSS {rss0 / MB:.1f} -> {rss1 / MB:.1f} MB ({(rss1 - rss0) / MB:+.1f}), fds {fds0} -> {fds1}, "
        f"threads {threads0} -> {threads1}"
    )
    assert rss1 - rss0 < MAX_GROWTH
    assert fds1 <= fds0 and threads1 <= threads0


@pytest.mark.slow
def test_100k_steps_and_10k_resets_of_a_kinematic_env_keep_memory_and_fds_flat() -> None:
    # episode.max_steps=10: every episode is at most 10 steps, so 100,000 steps make at least 10,000 resets
    env = RoverNavEnv(config=compose(FLAT_TINY))
    try:
        check_no_growth(
            "kinematic, flat, 16 x 12",
            functools.partial(drive, env, 100_000, 1),
            functools.partial(drive, env, 2_000, 0),
        )
    finally:
        env.close()


@pytest.mark.slow
def test_mars_yard_with_the_default_camera_keeps_memory_and_fds_flat() -> None:
    env = RoverNavEnv(config=compose(["world=mars_yard", "episode.max_steps=10"]))
    try:
        check_no_growth(
            "kinematic, mars_yard, 64 x 48",
            functools.partial(drive, env, 10_000, 1),
            functools.partial(drive, env, 1_000, 0),
        )
    finally:
        env.close()


@pytest.mark.slow
def test_1000_physics_resets_leak_no_pybullet_client_fds_or_memory() -> None:
    """A reset settles the rover in the same client; a sim_error rebuilds it (every 100th episode here):
    neither may leave a client connected, a file open or memory behind."""
    env = RoverNavEnv(config=compose(["world=flat", "dynamics=physics", "sensor.width=16", "sensor.height=12"]))
    try:
        env.reset(seed=0)
        clients0 = pybullet_clients()
        assert len(clients0) == 1

        def resets(n: int, seed: int) -> tuple[int, int]:
            rng = np.random.default_rng(seed)
            for i in range(n):
                env.reset(seed=int(rng.integers(1 << 30)))
                if i % 100 == 99:  # blow the simulation up: the next reset rebuilds the client
                    scene = env.dynamics.scene()
                    pb.resetBaseVelocity(scene.robot_id, [math.nan] * 3, [0.0] * 3, physicsClientId=scene.client)
                    _, _, terminated, _, info = env.step(np.array([0.5, 0.0], dtype=np.float32))
                    assert terminated and info["outcome"] == "sim_error"
            return 0, n

        check_no_growth("physics resets", functools.partial(resets, 1_000, 1), functools.partial(resets, 100, 0))
        assert len(pybullet_clients()) == 1
        probe = pb.connect(pb.DIRECT)  # a fresh client gets the lowest free id: 1 if only the env's is taken
        pb.disconnect(probe)
        assert probe <= max(clients0) + 1
    finally:
        env.close()
    assert pybullet_clients() == []


def test_closing_a_subproc_vec_env_leaves_no_worker_processes() -> None:
    from diana_lab.config.run import TrainConfig
    from diana_lab.training.envs import make_training_env

    cfg = compose([*FLAT_TINY, "world.size_x=20", "world.size_y=20"])
    me = psutil.Process()
    before = {p.pid for p in me.children(recursive=True)}
    venv = make_training_env(cfg, TrainConfig(n_envs=2, vec_env="subproc"), seed=0)
    workers = [psutil.Process(p.pid) for p in venv.processes]
    assert all(w.is_running() for w in workers)
    venv.reset()
    venv.step(np.zeros((2, 2), dtype=np.float32))
    venv.close()
    gone, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive
    # what may outlive close(): multiprocessing's own helpers (forkserver, resource tracker), never a worker
    extra = [p for p in me.children(recursive=True) if p.pid not in before and p.is_running()]
    helpers = ("forkserver", "resource_tracker", "semaphore_tracker")
    assert all(any(h in " ".join(p.cmdline()) for h in helpers) for p in extra), [p.cmdline() for p in extra]
