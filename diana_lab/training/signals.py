"""Ctrl-C and SIGTERM as exceptions raised at safe points, so a run always ends cleanly.

SIGTERM (``kill``, a job scheduler, a container stop; under submitit also its time-limit signal) becomes
:class:`Terminated`, a ``KeyboardInterrupt``,
so it is handled exactly like Ctrl-C: checkpoint saved, MLflow run marked KILLED, instead of the process
dying mid-write with the run left RUNNING. Both are deferred while a tracking-store write is in progress
(:mod:`diana_lab.tracking.atomic`).

Python swallows an exception raised while a finalizer or a weakref callback runs ("Exception ignored in
..."), and a signal can land there (SQLAlchemy's garbage-collection hooks, for one): the interrupt would be
lost and training go on. So the handler also remembers the interrupt, and safe points raise it again if it
never arrived: :class:`InterruptCheck` on every training step, and :func:`raise_pending` elsewhere.

Native code can wrap it, too: an interrupt that lands while numba's dispatcher runs (compiling or unpickling a
kernel, as the sensor's ray caster does on its first calls) comes out as ``SystemError: ... returned a result
with an exception set``, the interrupt its cause. :func:`unwrapped_interrupts` raises the interrupt itself again,
so the run still ends KILLED with its checkpoint, not FAILED.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator
from types import FrameType

from stable_baselines3.common.callbacks import BaseCallback

from diana_lab.tracking import atomic

__all__ = [
    "InterruptCheck",
    "Terminated",
    "interrupt_exit_code",
    "interrupts_as_exceptions",
    "raise_pending",
    "unwrapped_interrupts",
]

_pending: BaseException | None = None  # the last interrupt, until it propagates out of interrupts_as_exceptions


class Terminated(KeyboardInterrupt):
    """Raised in the main thread when the process receives SIGTERM."""


def _scheduler_signals() -> tuple[signal.Signals, ...]:
    """Under submitit (``hydra/launcher=submitit_slurm``), the signal Slurm sends before the job's time limit
    (``SUBMITIT_PREEMPT_SIGNAL``, USR2 by default): submitit would raise an error mid-step, ending the run FAILED
    with no checkpoint; taken as SIGTERM it ends KILLED with one (``train.resume`` continues it)."""
    if not os.environ.get("SUBMITIT_EXECUTOR"):
        return ()
    name = "SIG" + os.environ.get("SUBMITIT_PREEMPT_SIGNAL", "USR2")
    return (signal.Signals[name],) if name in signal.Signals.__members__ else ()


def _handler(signum: int, frame: FrameType | None) -> None:
    global _pending
    exc: BaseException = (
        KeyboardInterrupt() if signum == signal.SIGINT else Terminated(f"received {signal.Signals(signum).name}")
    )
    _pending = exc
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
    global _pending
    previous = {s: signal.signal(s, _handler) for s in (signal.SIGINT, signal.SIGTERM, *_scheduler_signals())}
    try:
        yield
    except BaseException:
        _pending = None  # delivered: it is propagating now
        raise
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    raise_pending()  # an interrupt swallowed inside the block


@contextlib.contextmanager
def unwrapped_interrupts() -> Iterator[None]:
    """Within the block, an exception caused by an interrupt (native code wrapped it: module docstring) is raised
    as that interrupt."""
    try:
        yield
    except Exception as exc:
        interrupt = _interrupt_behind(exc)
        if interrupt is None:
            raise
        raise interrupt from exc


def _interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The ``KeyboardInterrupt`` in ``exc``'s chain of causes and contexts, if any."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


def raise_pending() -> None:
    """Raise an interrupt that a handler raised where Python swallowed it (see the module docstring)."""
    global _pending
    if _pending is not None:
        exc, _pending = _pending, None
        raise exc


class InterruptCheck(BaseCallback):
    """A safe point on every training step: raises an interrupt that never arrived."""

    def _on_step(self) -> bool:
        raise_pending()
        return True


def interrupt_exit_code(exc: BaseException) -> int:
    """The shell convention 128 + signal number: 143 for SIGTERM, 130 for SIGINT (Ctrl-C)."""
    return 128 + (signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT)
