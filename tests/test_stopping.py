"""Stopping on a signal: SIGTERM outside a fit stops at once, a stop is named after the first signal,
submitit's requeue exit becomes a stop, the handlers before a run come back after it."""

from __future__ import annotations

import os
import signal
from typing import Any

import pytest
from lightning.pytorch.utilities.exceptions import SIGTERMException

from lossvo.training.stopping import InterruptedRun, StopSignals


def _submitit(exits: bool) -> Any:
    """A stand-in for submitit's requeue handler (submitit's module name): requeues, then exits or not."""

    def handler(signum: int, frame: Any) -> None:
        handler.calls += 1  # type: ignore[attr-defined]
        if exits:
            raise SystemExit(-1)

    handler.calls = 0  # type: ignore[attr-defined]
    handler.__module__ = "submitit.core.job_environment"
    return handler


@pytest.fixture
def usr2():
    previous = signal.getsignal(signal.SIGUSR2)
    yield
    signal.signal(signal.SIGUSR2, previous)


def test_sigterm_outside_a_fit_stops_at_once_and_handlers_are_restored() -> None:
    signals = StopSignals()
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    with pytest.raises(InterruptedRun) as caught, signals.installed():
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("SIGTERM did not stop the block")
    stop = caught.value
    assert (stop.signal_name, stop.epoch, stop.exit_code) == ("SIGTERM", None, 143)
    assert stop.stage == "the evaluation"
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before
    assert signals.first is None  # forgotten after the run


def test_sigint_is_recorded_and_raises_keyboard_interrupt() -> None:
    signals = StopSignals()
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with signals.installed():
            with pytest.raises(KeyboardInterrupt):
                os.kill(os.getpid(), signal.SIGINT)
            assert signals.first == "SIGINT"
            plain_exit = SystemExit(1)
            assert signals.stop(plain_exit, 2) is plain_exit  # not a stop by itself
            exit_after_interrupt = SystemExit(1)  # Lightning's, after a KeyboardInterrupt in a fit
            exit_after_interrupt.__context__ = KeyboardInterrupt()
            stop = signals.stop(exit_after_interrupt, 2)
            assert isinstance(stop, InterruptedRun) and (stop.signal_name, stop.epoch) == ("SIGINT", 2)
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_stop_is_named_after_the_signal_that_started_it(usr2: None) -> None:
    """SLURM's SIGTERM follows submitit's requeue on SIGUSR2 and may end the fit first (Lightning's
    SIGTERMException): the stop is still SIGUSR2's (exit status 140), and the SIGTERM does not interrupt
    the stop. Without an earlier signal a SIGTERMException is SIGTERM's; other errors stay as they are."""
    requeue = _submitit(exits=True)
    signal.signal(signal.SIGUSR2, requeue)
    signals = StopSignals()
    with signals.installed():
        with pytest.raises(InterruptedRun, match="SIGUSR2 during the evaluation"):
            os.kill(os.getpid(), signal.SIGUSR2)
        os.kill(os.getpid(), signal.SIGTERM)  # no second InterruptedRun
        stop = signals.stop(SIGTERMException(), 289)
        assert isinstance(stop, InterruptedRun)
        assert (stop.signal_name, stop.epoch, stop.exit_code) == ("SIGUSR2", 289, 140)
    assert requeue.calls == 1 and signal.getsignal(signal.SIGUSR2) is requeue
    stop = signals.stop(SIGTERMException(), 3)
    assert isinstance(stop, InterruptedRun) and (stop.signal_name, stop.exit_code) == ("SIGTERM", 143)
    error = ValueError("not a stop")
    assert signals.stop(error, 3) is error


def test_a_process_that_submitit_does_not_exit_goes_on(usr2: None) -> None:
    """A DDP rank above 0: submitit requeues from rank 0 only; this process is not stopped, and a later
    SIGTERM is then the stop's cause."""
    requeue = _submitit(exits=False)
    signal.signal(signal.SIGUSR2, requeue)
    signals = StopSignals()
    with pytest.raises(InterruptedRun, match="SIGTERM"), signals.installed():
        os.kill(os.getpid(), signal.SIGUSR2)
        assert requeue.calls == 1 and signals.first is None
        os.kill(os.getpid(), signal.SIGTERM)
