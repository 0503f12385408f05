from __future__ import annotations

import pytest

from tests.compare.store import make_store


@pytest.fixture(scope="session")
def compare_store(tmp_path_factory):
    """The comparison tests' store of runs with known numbers (two seeds of one config among them)."""
    return make_store(tmp_path_factory.mktemp("nb_store"))
