"""Ctrl-C and SIGTERM as exceptions raised at safe points, so a run always ends cleanly.

SIGTERM (``kill``, a job scheduler, a container stop) becomes :class:`Terminated`, a ``KeyboardInterrupt``,
so it is handled exactly like Ctrl-C: checkpoint saved, MLflow run marked KILLED, instead of the process
dying mid-write with the run left RUNNING. Both are deferred while a tracking-store write is in progress
(:mod:`diana_lab.tracking.atomic`).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

from diana_lab.tracking import atomic

__all__ = ["Terminated", "interrupt_exit_code", "interrupts_as_exceptions"]


class Terminated(KeyboardInterrupt):
    """Raised in the main thread when the process receives SIGTERM."""


def _handler(signum: int, frame: FrameType | None) -> None:
    exc: BaseException = (
        Terminated(f"received {signal.Signals(signum).name}") if signum == signal.SIGTERM else KeyboardInterrupt()
    )
    if atomic.active():
        atomic.defer(exc)
        return
    raise exc


@contextlib.contextmanager
def interrupts_as_exceptions() -> Iterator[None]:
    """Within the block SIGINT raises ``KeyboardInterrupt`` and SIGTERM :class:`Terminated` (both deferred
    during store writes); the previous handlers are restored afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be installed from the main thread
        return
    previous = {s: signal.signal(s, _handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def interrupt_exit_code(exc: BaseException) -> int:
    """The shell convention 128 + signal number: 143 for SIGTERM, 130 for SIGINT (Ctrl-C)."""
    return 128 + (signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT)
