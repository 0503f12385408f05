"""The source revision a run was trained from (read-only git queries; "unknown" outside a checkout)."""

from __future__ import annotations

import subprocess
from pathlib import Path

__all__ = ["REPO_ROOT", "git_commit", "git_dirty"]

REPO_ROOT = Path(__file__).resolve().parents[2]


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(["git", *args], cwd=REPO_ROOT, capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def git_commit() -> str:
    return _git("rev-parse", "HEAD") or "unknown"


def git_dirty() -> bool | None:
    """Whether tracked files differ from the commit (``None`` when unknown): such a run is not reproducible
    from the commit alone."""
    out = _git("status", "--porcelain", "--untracked-files=no")
    return None if out is None else bool(out)
