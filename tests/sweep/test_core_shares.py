"""sweep.workers: how the cores are shared out and what each worker is started with."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from diana_lab.config import ConfigError
from diana_lab.config.sweep import SweepConfig
from diana_lab.sweeps.workers import core_shares, worker_command


@pytest.mark.parametrize(
    ("cores", "workers", "shares"),
    [
        ([0, 1], 2, [[0], [1]]),
        ([0, 1, 2, 3, 4], 2, [[0, 1, 2], [3, 4]]),
        ([4, 5, 6, 7], 4, [[4], [5], [6], [7]]),
        ([0, 1], 3, [[0], [1], [0]]),  # more workers than cores: they share round robin
        ([0, 1, 2], 1, [[0, 1, 2]]),
    ],
)
def test_core_shares_cover_every_core_once_when_they_can(cores, workers, shares):
    assert core_shares(cores, workers) == shares


def test_worker_command_is_the_same_study_with_one_worker_its_own_dir_and_seed():
    cmd = worker_command(
        ["sweep.name=reward_shaping", "sweep.workers=2", "sweep.sampler_seed=5", "seed=3", "sweep.storage=x.journal"],
        1,
        "/abs/x.journal",
        Path("/runs/s"),
        5,
        ["hydra.run.dir=/runs/s", "hydra/job_logging=disabled"],
    )
    assert cmd[:3] == [sys.executable, "-m", "diana_lab.sweep"]
    args = cmd[3:]
    assert "sweep.workers=1" in args and "sweep.workers=2" not in args
    assert "sweep.storage=/abs/x.journal" in args and "sweep.storage=x.journal" not in args
    assert "sweep.sampler_seed=5" not in args and any(a.startswith("sweep.sampler_seed=") for a in args)
    assert "seed=3" in args and "sweep.name=reward_shaping" in args
    assert "hydra/job_logging=disabled" in args and args[-1] == "hydra.run.dir=/runs/s/worker_1"
    assert "hydra.run.dir=/runs/s" not in args


@pytest.mark.parametrize("bad", [0, -1, True, 1.5])
def test_workers_must_be_a_positive_integer(bad):
    with pytest.raises(ConfigError, match=r"sweep\.workers"):
        SweepConfig(workers=bad)
