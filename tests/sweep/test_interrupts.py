"""An interrupt whose exception Python swallows (raised inside a finalizer) is raised at the next safe point,
so Ctrl-C always stops a sweep's trial instead of being lost with an "Exception ignored" message."""

from __future__ import annotations

import gc
import signal

import pytest

from diana_lab.training import signals
from diana_lab.training.signals import InterruptCheck, interrupts_as_exceptions

pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")


class _SignalInFinalizer:
    """Garbage whose finalizer receives the signal, as SQLAlchemy's gc hooks can."""

    def __init__(self, signum: int) -> None:
        self.signum = signum

    def __del__(self) -> None:
        signals._handler(self.signum, None)


def _swallow(signum: int = signal.SIGINT) -> None:
    _SignalInFinalizer(signum)
    gc.collect()


def test_the_next_training_step_raises_a_swallowed_interrupt():
    swallowed = False
    with pytest.raises(KeyboardInterrupt), interrupts_as_exceptions():
        _swallow()
        swallowed = True  # Python dropped the handler's exception: we are still here
        InterruptCheck()._on_step()
        pytest.fail("the training step went on")
    assert swallowed


def test_leaving_the_block_raises_a_swallowed_sigterm():
    swallowed = False
    with pytest.raises(signals.Terminated), interrupts_as_exceptions():
        _swallow(signal.SIGTERM)
        swallowed = True
    assert swallowed


def test_a_delivered_interrupt_is_not_raised_twice():
    with pytest.raises(KeyboardInterrupt), interrupts_as_exceptions():
        signals._handler(signal.SIGINT, None)
    InterruptCheck()._on_step()  # nothing pending any more
