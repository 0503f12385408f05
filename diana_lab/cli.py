"""Thin Hydra entry points: every ``python -m diana_lab.<entry>`` is a Hydra app over the same ``conf/`` tree.

:func:`hydra_app` wraps a task ``fn(cfg)`` so that mistakes a user can make (bad values, missing files, a
policy trained for another observation space) print one paragraph naming the key or file and exit with
status 2, without a Python traceback unless ``HYDRA_FULL_ERROR=1`` is set. Hydra itself reports misspelt
groups, options and keys the same way. Every group with a schema is range-checked before the task starts (so
a bad value fails in about a second, before torch is imported), and :class:`OutputDirCheck` does the same
for a run folder that cannot be created. What the entry points accept and refuse: ``docs/reliability.md``.
"""

from __future__ import annotations

import functools
import logging
import os
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import hydra
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from diana_lab.config import CONF_DIR, POLICY_CONFIGS, SCHEMAS, ConfigError, store_schemas, validate
from diana_lab.config.policy import source_overrides
from diana_lab.errors import UserError, output_file  # noqa: F401  (the entry points' names for them)
from diana_lab.hydra_run import task_overrides  # noqa: F401
from diana_lab.run_log import console_to_log_file, log_only

USER_ERRORS: tuple[type[BaseException], ...] = (ConfigError, FileNotFoundError, ValueError)
EXIT_USER_ERROR = 2


def full_error() -> bool:
    """Whether the user asked for tracebacks: ``HYDRA_FULL_ERROR=1``, read as Hydra reads it (only ``1``: ``0``
    or anything else is no)."""
    return os.environ.get("HYDRA_FULL_ERROR") == "1"


def report(exc: BaseException) -> None:
    """Print one paragraph about a user error (the first line of the message, wrapped)."""
    message = str(exc).strip() or type(exc).__name__
    print(f"error: {message}", file=sys.stderr)
    if not full_error():
        print("(set HYDRA_FULL_ERROR=1 for the full traceback)", file=sys.stderr)


class OutputDirCheck(Callback):
    """Hydra callback (``hydra.callbacks.output_dir`` in ``conf/config.yaml``): checks that the run (or sweep)
    folder can be created before Hydra creates it, since Hydra reports that failure with its own traceback.
    Only looks at the nearest existing ancestor (no side effect: the folder name may hold ``${now:...}``).
    With ``HYDRA_FULL_ERROR=1`` it stays out of the way and Hydra's traceback shows."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, "hydra.run.dir")

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, "hydra.sweep.dir")

    @staticmethod
    def _check(config: DictConfig, key: str) -> None:
        if full_error():
            return
        try:
            value = OmegaConf.select(config, key)
        except Exception:  # an interpolation only Hydra can resolve here: leave the check to Hydra
            return
        if not value:
            return
        path = Path(str(value)).expanduser().absolute()
        existing = next(p for p in (path, *path.parents) if p.exists())
        problem = (
            f"'{existing}' is a file"
            if not existing.is_dir()
            else f"'{existing}' is not writable"
            if not os.access(existing, os.W_OK | os.X_OK)
            else None
        )
        if problem:
            report(UserError(f"{key}={value}: cannot create the output folder: {problem}"))
            sys.exit(EXIT_USER_ERROR)


class TrackingStoreReady(Callback):
    """Hydra callback (``hydra.callbacks.tracking_store`` in ``conf/config.yaml``): before a multirun's jobs start
    in parallel (``hydra/launcher=joblib``, ``submitit_*``), creates the tables of a new SQLite tracking store
    once, here, so that the jobs do not all find it empty and create them at the same time (MLflow does that
    unguarded and the losers fail). The basic launcher runs its jobs one after the other and needs none of this."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        target = str(OmegaConf.select(config, "hydra.launcher._target_", default="") or "")
        if target.endswith("BasicLauncher") or not OmegaConf.select(config, "tracking.enabled", default=False):
            return
        uri = OmegaConf.select(config, "tracking.uri", default=None)
        if not uri or not str(uri).startswith("sqlite:"):
            return
        from diana_lab.tracking.mlflow_run import writable_store

        for name in ("mlflow", "alembic"):  # their INFO lines on a new store: noise before the jobs' output
            logging.getLogger(name).setLevel(logging.WARNING)
        try:
            resolved = writable_store(str(uri))
            from mlflow.tracking import MlflowClient

            MlflowClient(resolved).search_experiments(max_results=1)  # opening the store creates its tables
        except (*USER_ERRORS, UserError) as exc:
            if full_error():
                raise
            report(exc)
            sys.exit(EXIT_USER_ERROR)


def hydra_app(
    config_name: str = "config", combinations: bool = True
) -> Callable[[Callable[[DictConfig], Any]], Callable[[], None]]:
    """Decorator: turn ``task(cfg)`` into a console ``main()`` composed from ``conf/<config_name>.yaml``.
    ``combinations=False``: only each group's own checks up front, for a task that takes some groups from
    elsewhere (the export takes ``action_space`` from the training config, and checks the shield against that)."""

    def decorator(task: Callable[[DictConfig], Any]) -> Callable[[], None]:
        @functools.wraps(task)
        def guarded(cfg: DictConfig) -> Any:
            # the console's lines (progress, summaries, notes, errors) also go to the job's log file
            with console_to_log_file():
                try:
                    # every group's range checks before the task imports its stack (torch, open3d, SB3: seconds),
                    # so a bad value fails in about a second; the tasks check again where they build things
                    validate(cfg, [g for g in cfg if g in SCHEMAS], combinations)
                    return task(cfg)
                except (*USER_ERRORS, UserError) as exc:
                    if full_error():
                        raise
                    report(exc)
                    sys.exit(EXIT_USER_ERROR)
                except Exception:  # a bug: Hydra prints the traceback after the job, so the log file gets it here
                    log_only("the job failed:\n" + traceback.format_exc().rstrip(), logging.ERROR)
                    raise

        def main() -> None:
            # MLflow logs at INFO when it creates a store or migrates one: noise around a one-paragraph error
            # (a user's MLFLOW_LOGGING_LEVEL still wins)
            os.environ.setdefault("MLFLOW_LOGGING_LEVEL", "WARNING")
            store_schemas()
            if config_name in POLICY_CONFIGS:  # policy=<path or run id>: policy=model policy.source=<it>
                sys.argv[1:] = source_overrides(sys.argv[1:], CONF_DIR)
            hydra.main(config_path=str(CONF_DIR), config_name=config_name, version_base="1.3")(guarded)()

        main.task = task  # type: ignore[attr-defined]
        return main

    return decorator
