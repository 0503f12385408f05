"""Torch's thread count per phase of training: few while the envs step, every core while the networks learn.

Why: during a rollout the envs (the batched env's compiled kernels, or the subprocesses) and the policy's small
forward passes share the cores, and a second OpenMP thread of torch's only spins against them; during the gradient
updates the envs wait, and every core can work on the minibatches (docs/batched.md has the timings).
"""

from __future__ import annotations

import os

import torch
from stable_baselines3.common.callbacks import BaseCallback

from diana_lab.core.validation import ConfigError

__all__ = ["PhaseThreads", "available_cores", "check_overlap", "core_ids", "phase_threads"]


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


def check_overlap(overlap: bool, off_policy: bool, algo_name: str) -> None:
    """Refuse ``train.overlap`` for an off-policy algorithm (it learns between env steps: there is no rollout to
    collect during an update)."""
    if overlap and off_policy:
        raise ConfigError(
            f"train.overlap=true: algo={algo_name} is off-policy and learns between env steps, so there is no "
            "rollout to collect during its update; use an on-policy algorithm (algo=ppo, algo=a2c) or "
            "train.overlap=false"
        )


def phase_threads(torch_threads: int, update_threads: int, overlap: bool) -> PhaseThreads:
    """The runner's :class:`PhaseThreads`: ``train.torch_threads`` while the envs step and ``train.update_threads``
    during the updates; with ``overlap`` the two run at once, so ``train.torch_threads`` in both (a second
    OpenMP thread in the update spins against the rollout's thread)."""
    rollout = torch_threads or None
    return PhaseThreads(rollout, (torch_threads or None) if overlap else update_threads)
