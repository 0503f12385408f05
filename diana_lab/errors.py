"""The mistakes a user can make that are not config values, and the output path check every entry point shares.

Library modules raise :class:`UserError` (an unknown run id, a model file that is not one, an output folder that
cannot be written); the entry points (:mod:`diana_lab.cli`) turn it, like a :class:`~diana_lab.config.ConfigError`,
into one paragraph and exit status 2. Here, below every layer, so that no library module imports the CLI.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

__all__ = ["UserError", "output_file"]


class UserError(RuntimeError):
    """Raised by entry points for user mistakes that are not config values (e.g. an unknown run id)."""


def output_file(value: Any, key: str = "output") -> Path:
    """The path of an output file the user named, with its folder created now: a folder that cannot be made
    (a read-only place, a file in the way) fails before the work, naming the key, not as an ``OSError``
    after it."""
    path = Path(str(value)).expanduser()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        why = "a file is in the way" if isinstance(exc, FileExistsError | NotADirectoryError) else exc.strerror
        raise UserError(f"{key}={value}: cannot create the folder '{path.parent}' ({why or exc})") from exc
    if path.is_dir():
        raise UserError(f"{key}={value}: '{path}' is a folder; expected a file path")
    if not os.access(path.parent, os.W_OK):
        raise UserError(f"{key}={value}: the folder '{path.parent}' is not writable")
    return path
