"""Interrupts that native code wrapped still end a run as interrupts (training.signals.unwrapped_interrupts)."""

from __future__ import annotations

import pytest

from diana_lab.training.signals import Terminated, unwrapped_interrupts

from .helpers import ALGO_TINY, TINY, run_in_process, runs, store_args


def wrapped(interrupt: BaseException, as_cause: bool = True) -> SystemError:
    """What numba's dispatcher raises when a signal handler raised inside it."""
    try:
        try:
            raise interrupt
        except BaseException as inner:
            if as_cause:
                raise SystemError(
                    "CPUDispatcher(<function raster_near>) returned a result with an exception set"
                ) from inner
            raise SystemError("returned a result with an exception set")  # noqa: B904 (implicit context)
    except SystemError as outer:
        return outer


@pytest.mark.parametrize("as_cause", [True, False])
@pytest.mark.parametrize("interrupt", [Terminated("received SIGTERM"), KeyboardInterrupt()])
def test_a_wrapped_interrupt_is_raised_as_itself(interrupt, as_cause):
    with pytest.raises(type(interrupt)) as got, unwrapped_interrupts():
        raise wrapped(interrupt, as_cause)
    assert got.value is interrupt


def test_a_doubly_wrapped_interrupt_is_found_and_other_errors_pass_unchanged():
    interrupt = Terminated("received SIGTERM")
    try:
        raise RuntimeError("outer") from wrapped(interrupt)
    except RuntimeError as exc:
        outer = exc
    with pytest.raises(Terminated), unwrapped_interrupts():
        raise outer
    error = SystemError("a real one")
    with pytest.raises(SystemError) as got, unwrapped_interrupts():
        raise error
    assert got.value is error


@pytest.mark.parametrize("vec_env", ["batched", "dummy"])
def test_a_sigterm_wrapped_by_native_code_ends_the_run_killed_with_its_checkpoint(
    vec_env, tmp_path, monkeypatch, capsys
):
    """The interrupt CI once met: SIGTERM landed while numba compiled the ray caster, and the run ended FAILED
    (exit 1, a traceback) instead of KILLED (exit 143). The scalar envs' caster and the batched env's alike."""
    from diana_lab.envs.batched.sensing import BatchedSensor
    from diana_lab.sensing.sensor import RaySensor

    owner, name, after = (RaySensor, "capture", 300) if vec_env == "dummy" else (BatchedSensor, "observe", 80)
    real, calls = getattr(owner, name), []

    def interrupted(self, *args):  # the sensor's numba caster, interrupted after two rollouts
        calls.append(1)
        if len(calls) > after:
            raise wrapped(Terminated("received SIGTERM"))
        return real(self, *args)

    monkeypatch.setattr(owner, name, interrupted)
    code = run_in_process(["algo=ppo", *TINY, *ALGO_TINY["ppo"], f"train.vec_env={vec_env}", *store_args(tmp_path)])
    err = capsys.readouterr().err
    assert code == 143, err
    assert "Traceback" not in err and "interrupted at" in err, err
    _, found = runs(tmp_path)
    assert [r.info.status for r in found] == ["KILLED"]
    assert any((tmp_path / "run" / "checkpoints").glob("rl_model_*_steps.zip"))


@pytest.mark.parametrize(("env", "caught"), [({}, False), ({"SUBMITIT_EXECUTOR": "slurm"}, True)])
def test_under_submitit_the_time_limit_signal_ends_the_block_as_a_sigterm(monkeypatch, env, caught):
    import os
    import signal

    from diana_lab.training.signals import interrupts_as_exceptions

    monkeypatch.delenv("SUBMITIT_EXECUTOR", raising=False)
    monkeypatch.delenv("SUBMITIT_PREEMPT_SIGNAL", raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    seen = []

    def own(signum, frame):
        seen.append(signum)

    previous = signal.signal(signal.SIGUSR2, own)
    try:
        if caught:
            with pytest.raises(Terminated, match="SIGUSR2"), interrupts_as_exceptions():
                os.kill(os.getpid(), signal.SIGUSR2)
            assert seen == []
        else:
            with interrupts_as_exceptions():
                os.kill(os.getpid(), signal.SIGUSR2)
            assert seen == [signal.SIGUSR2]  # outside submitit the signal keeps its own handler
        assert signal.getsignal(signal.SIGUSR2) is own  # restored after the block
    finally:
        signal.signal(signal.SIGUSR2, previous)
