"""Thin Hydra entry points: every ``python -m diana_lab.<entry>`` is a Hydra app over the same ``conf/`` tree.

:func:`hydra_app` wraps a task ``fn(cfg)`` so that mistakes a user can make (bad values, missing files, a
policy trained for another observation space) print one paragraph naming the key or file and exit with
status 2, without a Python traceback unless ``HYDRA_FULL_ERROR=1`` is set. Hydra itself reports misspelt
groups, options and keys the same way.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import Any

import hydra
from omegaconf import DictConfig

from diana_lab.config import CONF_DIR, ConfigError, store_schemas

USER_ERRORS: tuple[type[BaseException], ...] = (ConfigError, FileNotFoundError, ValueError)
EXIT_USER_ERROR = 2


class UserError(RuntimeError):
    """Raised by entry points for user mistakes that are not config values (e.g. an unknown run id)."""


def report(exc: BaseException) -> None:
    """Print one paragraph about a user error (the first line of the message, wrapped)."""
    message = str(exc).strip() or type(exc).__name__
    print(f"error: {message}", file=sys.stderr)
    if not os.environ.get("HYDRA_FULL_ERROR"):
        print("(set HYDRA_FULL_ERROR=1 for the full traceback)", file=sys.stderr)


def hydra_app(config_name: str = "config") -> Callable[[Callable[[DictConfig], Any]], Callable[[], None]]:
    """Decorator: turn ``task(cfg)`` into a console ``main()`` composed from ``conf/<config_name>.yaml``."""

    def decorator(task: Callable[[DictConfig], Any]) -> Callable[[], None]:
        @functools.wraps(task)
        def guarded(cfg: DictConfig) -> Any:
            try:
                return task(cfg)
            except (*USER_ERRORS, UserError) as exc:
                if os.environ.get("HYDRA_FULL_ERROR"):
                    raise
                report(exc)
                sys.exit(EXIT_USER_ERROR)

        def main() -> None:
            store_schemas()
            hydra.main(config_path=str(CONF_DIR), config_name=config_name, version_base="1.3")(guarded)()

        main.task = task  # type: ignore[attr-defined]
        return main

    return decorator
