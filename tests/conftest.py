"""Shared fixtures: worlds and robots composed from the real ``conf/`` tree."""

from __future__ import annotations

import logging
import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

from hypothesis import settings

# CI runs the same examples every time (reproducible); locally hypothesis explores new ones
settings.register_profile("ci", derandomize=True, database=None)
if os.environ.get("CI"):
    settings.load_profile("ci")

from diana_lab.config import build, compose, to_object  # noqa: E402  (after the environment is set)


@pytest.fixture(scope="session")
def mars_yard():
    return build(to_object("world", "mars_yard"))


@pytest.fixture(scope="session")
def flat_world():
    return build(to_object("world", "flat"))


@pytest.fixture(scope="session")
def hills_world():
    return build(to_object("world", "hills"))


@pytest.fixture(scope="session")
def craters_world():
    return build(to_object("world", "craters"))


@pytest.fixture(scope="session")
def jackal():
    return to_object("robot", "jackal")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def world_from_config(overrides: list[str]):
    """A world from ``world=...`` overrides (only the world group is composed)."""
    name = next(o.split("=", 1)[1] for o in overrides if o.startswith("world="))
    rest = [o for o in overrides if not o.startswith("world=")]
    cfg = compose(rest, config_name=f"world/{name}")
    return build(to_object("world", cfg.world))


@pytest.fixture(autouse=True)
def _package_loggers_enabled():
    """An in-process run with ``hydra/job_logging=disabled`` disables every logger that exists then
    (``disable_existing_loggers``), for the rest of the worker's tests: a later test of a warning would read
    nothing. Each test starts with the package's loggers on, as a fresh process has them."""
    for name, logger in list(logging.root.manager.loggerDict.items()):
        if name.startswith("diana_lab") and isinstance(logger, logging.Logger):
            logger.disabled = False
    yield
