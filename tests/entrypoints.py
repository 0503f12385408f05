"""Run an entry module (``python -m <module> <args>``) in this process or as a subprocess, for CLI tests."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def run_in_process(module: str, args: list[str]) -> int:
    """``module.main()`` with ``args`` as its command line; the exit status (0 without ``sys.exit``)."""
    main = importlib.import_module(module).main
    saved = sys.argv
    sys.argv = [module, *args]
    try:
        main()
    except SystemExit as exc:
        return int(exc.code or 0)
    finally:
        sys.argv = saved
    return 0


def run_subprocess(module: str, args: list[str], cwd: Path, **kwargs: Any) -> subprocess.Popen:
    """``python -m module args`` from ``cwd`` with text pipes (stderr as given, default its own pipe)."""
    env = {**os.environ, "PYTHONHASHSEED": "0", "PYTHONPATH": str(ROOT)}
    env.pop("HYDRA_FULL_ERROR", None)
    kwargs.setdefault("stderr", subprocess.PIPE)
    return subprocess.Popen(
        [sys.executable, "-m", module, *args], cwd=cwd, env=env, stdout=subprocess.PIPE, text=True, **kwargs
    )
