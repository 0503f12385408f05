"""What the user sees while training: the outcome rates beside success, and plain lines where there is no terminal."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from diana_lab.training.progress import ProgressWithStats, outcome_rates
from diana_lab.training.threads import PhaseThreads, available_cores

from ..agents.fake_env import FakeRoverEnv


def test_outcome_rates_name_the_failures_that_matter_beside_success():
    assert outcome_rates([]) == "no episode ended yet"
    text = outcome_rates(["success"] * 6 + ["tipover"] * 2 + ["stuck", "timeout"])
    assert text == "success 60% tip-over 20% stuck 10% timeout 10%"
    # the rarer ones only when they happened
    assert outcome_rates(["success", "collision"]) == "success 50% tip-over 0% stuck 0% timeout 0% collision 50%"


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize("tty", [False, True])
def test_progress_prints_plain_lines_off_a_terminal_and_a_bar_on_one(tty):
    stream = _Terminal() if tty else io.StringIO()
    progress = ProgressWithStats(line_interval_s=0.0, stream=stream)
    assert progress.bar is tty
    model = PPO("MultiInputPolicy", FakeRoverEnv("elevation_map"), n_steps=32, batch_size=32, n_epochs=1, seed=0)
    model.learn(96, callback=progress)
    progress.close()
    lines = [line for line in stream.getvalue().splitlines() if line.startswith("[train]")]
    if tty:
        assert not lines  # the bar draws itself (to the console), no plain lines
    else:
        assert len(lines) >= 3 and lines[-1].startswith("[train] 96/96 steps (100%)")
        assert "steps/s" in lines[-1] and ("success" in lines[-1] or "no episode" in lines[-1])
    assert len(progress.outcomes) > 0


def test_phase_threads_use_every_core_for_updates_and_one_for_rollouts(monkeypatch):
    seen: list[tuple[str, int]] = []
    real = torch.set_num_threads
    phase = {"now": "start"}

    def record(n: int) -> None:
        seen.append((phase["now"], n))
        real(n)

    monkeypatch.setattr(torch, "set_num_threads", record)
    threads = PhaseThreads(1, 0)
    model = PPO("MultiInputPolicy", FakeRoverEnv("elevation_map"), n_steps=16, batch_size=16, n_epochs=1, seed=0)
    model.learn(48, callback=threads)
    assert (("start", 1) in seen) and seen.count(("start", available_cores())) >= 2
    assert [n for _, n in seen][:2] == [1, available_cores()]
    real(1)
    assert np.isfinite(available_cores())
