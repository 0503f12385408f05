"""Several workers of one study on one machine (``sweep.workers=N``), each on its own share of the cores.

Why: a trial is one training run, and one run does not use two cores well: the batched env's compiled kernels
and torch's small forward passes and updates scale poorly with threads (docs/batched.md), while two
single-threaded runs side by side each go about as fast as one run with both cores. So a study gets nearly N
times the trials from N workers, one per share of the cores, rather than from one worker with every core.

The command's own process is worker 0; it starts workers 1..N-1 as ``python -m diana_lab.sweep`` with the same
overrides once the study and its MLflow run exist (so they only reopen them), each pinned to its cores with its
console in ``<run dir>/worker_<i>.log`` and its trials under ``<run dir>/worker_<i>/``. The study's storage
shares out the trials as it does between machines. Ctrl-C or SIGTERM to worker 0 is passed on to the others as
SIGTERM (each in a process group of its own, so each gets one signal, not two). Worker 0 waits for the others
before it reports, so its table holds every trial.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

from diana_lab.training.threads import core_ids

__all__ = ["LocalWorkers", "core_shares", "pin_to"]

STOP_WAIT_S = 120.0  # how long a stopped worker gets to mark its trial FAIL and end its MLflow run
_SEED_STRIDE = 1_000_003  # sampler seeds of the workers: far apart, so a rerun's (seed + done) never meets them


def core_shares(cores: Sequence[int], workers: int) -> list[list[int]]:
    """Split ``cores`` into ``workers`` contiguous shares (the first ones one core larger when it does not divide);
    with fewer cores than workers, workers share cores round robin."""
    if workers <= len(cores):
        size, extra = divmod(len(cores), workers)
        out, start = [], 0
        for i in range(workers):
            end = start + size + (i < extra)
            out.append(list(cores[start:end]))
            start = end
        return out
    return [[cores[i % len(cores)]] for i in range(workers)]


def pin_to(cores: Sequence[int]) -> None:
    """This process on ``cores`` only, its numba and torch thread pools sized to them."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, set(cores))
    n = len(cores)
    os.environ["NUMBA_NUM_THREADS"] = str(n)
    if "numba" in sys.modules:  # imported already: its pool exists, so shrink what it uses
        import numba

        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    if "torch" in sys.modules:
        import torch

        torch.set_num_threads(n)


def _replace(overrides: Sequence[str], key: str, value: str) -> list[str]:
    kept = [o for o in overrides if o.lstrip("+~").split("=", 1)[0] != key]
    return [*kept, f"{key}={value}"]


def worker_command(
    overrides: Sequence[str],
    index: int,
    storage: str,
    run_dir: Path,
    sampler_seed: int | None,
    hydra_overrides: Sequence[str] = (),
) -> list[str]:
    """The command line of worker ``index``: the same study (absolute storage), one worker, its own run dir."""
    args = _replace(overrides, "sweep.workers", "1")
    args = _replace(args, "sweep.storage", storage)
    if sampler_seed is not None:
        args = _replace(args, "sweep.sampler_seed", str((sampler_seed + index * _SEED_STRIDE) % 2**32))
    hydra = [h for h in hydra_overrides if not h.startswith(("hydra.run.dir=", "hydra.sweep."))]
    return [sys.executable, "-m", "diana_lab.sweep", *args, *hydra, f"hydra.run.dir={run_dir / f'worker_{index}'}"]


@dataclass
class LocalWorkers:
    """Workers 1..N-1 of this study, started by worker 0 (see the module docstring)."""

    run_dir: Path
    procs: dict[int, subprocess.Popen] = field(default_factory=dict)
    logs: dict[int, Path] = field(default_factory=dict)

    @classmethod
    def start(
        cls,
        workers: int,
        overrides: Sequence[str],
        storage: str,
        run_dir: Path,
        sampler_seed: int | None,
        hydra_overrides: Sequence[str] = (),
    ) -> LocalWorkers:
        shares = core_shares(core_ids(), workers)
        pin_to(shares[0])
        self = cls(run_dir)
        for i in range(1, workers):
            log = run_dir / f"worker_{i}.log"
            command = worker_command(overrides, i, storage, run_dir, sampler_seed, hydra_overrides)
            env = {**os.environ, "NUMBA_NUM_THREADS": str(len(shares[i])), "HYDRA_FULL_ERROR": "0"}
            cores = set(shares[i])
            with log.open("w") as out:
                self.procs[i] = subprocess.Popen(
                    command,
                    stdout=out,
                    stderr=subprocess.STDOUT,
                    env=env,
                    process_group=0,
                    preexec_fn=partial(os.sched_setaffinity, 0, cores) if hasattr(os, "sched_setaffinity") else None,
                )
            self.logs[i] = log
            print(f"worker {i}: pid {self.procs[i].pid}, cores {shares[i]}, console in {log}", file=sys.stderr)
        print(f"worker 0 (this process): cores {shares[0]}", file=sys.stderr)
        return self

    def wait(self) -> dict[int, int]:
        """Wait for every worker; their exit statuses. A worker that failed is named with its log."""
        codes = {i: p.wait() for i, p in self.procs.items()}
        for i, code in codes.items():
            if code != 0:
                print(f"note: worker {i} exited with status {code}; its console is in {self.logs[i]}", file=sys.stderr)
        return codes

    def stop(self) -> None:
        """Pass an interrupt on (SIGTERM), give each worker time to settle its trial, then kill what is left."""
        for p in self.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for i, p in self.procs.items():
            try:
                p.wait(STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                print(f"note: worker {i} did not stop in {STOP_WAIT_S:.0f} s: killed", file=sys.stderr)
                p.kill()
                p.wait()
