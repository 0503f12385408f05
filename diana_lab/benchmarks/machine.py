"""Where a set of figures was measured: the machine, its load, the library versions and the thread settings.

Figures only compare across runs with this next to them: a second process on a 2-core machine halves every
single-core figure, so the load average is recorded before and after the run (and the share of CPU time
other processes used just before it started).
"""

from __future__ import annotations

import os
import platform
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

__all__ = ["cpu_model", "library_versions", "load_average", "machine_info", "pin_threads"]

LIBRARIES = {  # JSON key -> distribution names to try (open3d ships as open3d or open3d-cpu)
    "numpy": ("numpy",),
    "open3d": ("open3d-cpu", "open3d"),
    "numba": ("numba",),
    "pybullet": ("pybullet",),
    "torch": ("torch",),
    "stable_baselines3": ("stable_baselines3", "stable-baselines3"),
    "gymnasium": ("gymnasium",),
    "hydra_core": ("hydra-core",),
}


def cpu_model() -> str:
    """The ``model name`` line of /proc/cpuinfo (``platform.processor()`` where there is none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (runnable processes, all users), or None where unsupported."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None


def machine_info(cpu_sample_s: float = 0.5) -> dict[str, Any]:
    """Cores, CPU model, load average and how busy the CPUs were over ``cpu_sample_s`` before the run."""
    import psutil

    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count() or 1
    return {
        "cores": os.cpu_count(),
        "cores_usable": usable,
        "cpu_model": cpu_model(),
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "memory_gb": round(psutil.virtual_memory().total / 2**30, 1),
        "load_avg_before": load_average(),
        "cpu_busy_pct_before": psutil.cpu_percent(interval=cpu_sample_s),
    }


def library_versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {}
    for key, dists in LIBRARIES.items():
        out[key] = None
        for dist in dists:
            try:
                out[key] = metadata.version(dist)
                break
            except metadata.PackageNotFoundError:
                continue
    return out


def pin_threads() -> dict[str, Any]:
    """One torch thread (the single-core figures, and what training uses by default: ``train.torch_threads``);
    open3d casts are pinned per sensor (``sensor.nthreads=1``, see :class:`~diana_lab.benchmarks.core.BenchContext`)."""
    import torch

    torch.set_num_threads(1)
    return {
        "torch": torch.get_num_threads(),
        "open3d_cast": 1,
        "pybullet_raytest": 1,
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
    }
