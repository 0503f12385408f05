from __future__ import annotations

import pytest

from .store import make_store


@pytest.fixture(scope="session")
def store(tmp_path_factory):
    """(uri, folder) of a store with the known runs of :mod:`tests.compare.store`."""
    tmp = tmp_path_factory.mktemp("store")
    return make_store(tmp), tmp
