"""Where a checkpoint's files are: ``<dir>/rl_model_<steps>_steps.zip`` and its buffers, as SB3 names them.

Below training and evaluation alike: the training callbacks write checkpoints, the evaluation's loader and
``train.resume`` find them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

__all__ = ["MODEL_RE", "PREFIX", "Checkpoint", "latest_checkpoint"]

PREFIX = "rl_model"
MODEL_RE = re.compile(rf"^{PREFIX}_(\d+)_steps\.zip$")


@dataclass(frozen=True)
class Checkpoint:
    """The files of one checkpoint; the optional ones are ``None`` when absent."""

    steps: int
    model: Path
    vecnormalize: Path | None
    replay_buffer: Path | None

    @staticmethod
    def buffer_path(directory: Path, steps: int, kind: str) -> Path:
        """Where SB3's ``CheckpointCallback`` saves the ``kind`` (``vecnormalize``, ``replay_buffer``) of the
        checkpoint at ``steps``, whether or not it is there."""
        return directory / f"{PREFIX}_{kind}_{steps}_steps.pkl"

    @classmethod
    def at(cls, directory: Path, steps: int) -> Checkpoint:
        def maybe(kind: str) -> Path | None:
            p = cls.buffer_path(directory, steps, kind)
            return p if p.is_file() else None

        return cls(steps, directory / f"{PREFIX}_{steps}_steps.zip", maybe("vecnormalize"), maybe("replay_buffer"))


def latest_checkpoint(directory: Path) -> Checkpoint | None:
    """The checkpoint with the most steps in ``directory``, or ``None``."""
    if not directory.is_dir():
        return None
    steps = [int(m.group(1)) for p in directory.iterdir() if (m := MODEL_RE.match(p.name))]
    return Checkpoint.at(directory, max(steps)) if steps else None
