"""The kind of CPU a run trained on, as a tag (``host_cpu``).

Why: the same seed and code give bit-identical weights on one kind of CPU and different ones on another (floating
point reductions in the compiled kernels and in torch differ by instruction set), and the difference moves a
policy's evaluation as much as its seed does. A comparison must pair runs trained on the same kind of CPU;
``python -m diana_lab.compare`` reads this tag to say when it does not.
"""

from __future__ import annotations

import functools
import platform
from pathlib import Path

__all__ = ["HOST_TAG", "cpu_model"]

HOST_TAG = "host_cpu"
CPUINFO = Path("/proc/cpuinfo")


@functools.cache
def cpu_model(cpuinfo: Path = CPUINFO) -> str:
    """The CPU's model name (Linux's ``/proc/cpuinfo``; elsewhere ``platform.processor()``), never empty:
    ``"unknown <machine>"`` where neither names it."""
    try:
        for line in cpuinfo.read_text(errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return " ".join(value.split())
    except OSError:
        pass
    return platform.processor().strip() or f"unknown {platform.machine() or 'cpu'}"
