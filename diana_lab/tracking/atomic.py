"""Keep Ctrl-C and SIGTERM out of the middle of a tracking-store write.

An interrupt raised inside an SQLite commit can leave the connection holding the database's write lock;
the next write (ending the run as KILLED) then waits for the lock and fails, and the run stays RUNNING
forever. The runner's signal handler (:mod:`diana_lab.training.signals`) therefore asks :func:`active`
first: inside :func:`uninterrupted` it only records the interrupt, which is raised as soon as the write is
done.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

__all__ = ["active", "defer", "uninterrupted"]

_depth = 0
_pending: BaseException | None = None


def active() -> bool:
    """Whether a write that must not be interrupted is in progress."""
    return _depth > 0


def defer(exc: BaseException) -> None:
    """Remember an interrupt to raise when the current write ends (the first one wins)."""
    global _pending
    if _pending is None:
        _pending = exc


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    global _depth, _pending
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
    if _depth == 0 and _pending is not None:
        exc, _pending = _pending, None
        raise exc
