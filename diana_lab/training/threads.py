"""Torch's thread count per phase of training: few while the envs step, every core while the networks learn.

Why: during a rollout the envs (the batched env's compiled kernels, or the subprocesses) and the policy's small
forward passes share the cores, and a second OpenMP thread of torch's only spins against them; during the gradient
updates the envs wait, and every core can work on the minibatches (docs/batched.md has the timings).
"""

from __future__ import annotations

import os

import torch
from stable_baselines3.common.callbacks import BaseCallback

__all__ = ["PhaseThreads", "available_cores", "core_ids"]


def core_ids() -> list[int]:
    """The ids of the cores this process may run on, sorted."""
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux: no affinity, every core
        return list(range(os.cpu_count() or 1))


def available_cores() -> int:
    """How many cores this process may run on."""
    return len(core_ids())


class PhaseThreads(BaseCallback):
    """``rollout`` torch threads while collecting experience, ``update`` while learning from it (0: every core;
    ``None``: leave torch's setting alone in that phase)."""

    def __init__(self, rollout: int | None, update: int | None) -> None:
        super().__init__()
        self.rollout = rollout
        self.update = available_cores() if update == 0 else update

    def _on_rollout_start(self) -> None:
        if self.rollout:
            torch.set_num_threads(self.rollout)

    def _on_rollout_end(self) -> None:
        if self.update:
            torch.set_num_threads(self.update)

    def _on_step(self) -> bool:
        return True
