"""Stopping a run on a signal (SIGINT, SIGTERM, submitit's SIGUSR2): the first one to come, and the one
exception that says so. During a fit Lightning owns SIGTERM (this handler only records it); outside a fit
it raises :class:`InterruptedRun` at once. What a stopped run leaves: docs/training.md.
"""

from __future__ import annotations

import functools
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from lightning.pytorch.utilities.exceptions import SIGTERMException

Handler = Callable[[int, Any], Any]


class InterruptedRun(BaseException):
    """A run stopped by a signal (in ``epoch``, from 1; None outside training), raised from any code."""

    def __init__(self, signal_name: str, epoch: int | None = None) -> None:
        self.signal_name, self.epoch = signal_name, epoch
        super().__init__(f"{signal_name} during {self.stage}")

    @property
    def stage(self) -> str:
        return f"epoch {self.epoch}" if self.epoch is not None else "the evaluation"

    @property
    def exit_code(self) -> int:
        """128 + the signal number, as a shell reports a process ended by that signal."""
        return 128 + int(getattr(signal, self.signal_name))


class StopSignals:
    """The signals that stop a run, and the first of them to come (:attr:`first`, e.g. ``"SIGTERM"``)."""

    def __init__(self) -> None:
        self.first: str | None = None

    def _record(self, signum: int) -> bool:
        """Record a signal; whether it is the first (the stop's cause)."""
        if self.first is not None:
            return False
        self.first = signal.Signals(signum).name
        return True

    def _on_sigterm(self, signum: int, frame: Any) -> None:
        """SIGTERM: recorded; outside a fit (this handler installed, not Lightning's) the run stops here."""
        if self._record(signum) and signal.getsignal(signal.SIGTERM) == self._on_sigterm:
            raise InterruptedRun("SIGTERM")

    def _on_sigint(self, previous: Handler, signum: int, frame: Any) -> Any:
        """SIGINT: recorded, then the handler it had (Python's raises KeyboardInterrupt)."""
        self._record(signum)
        return previous(signum, frame)

    def _on_requeue(self, submitit: Handler, signum: int, frame: Any) -> None:
        """Submitit's requeue signal: its exit becomes an :class:`InterruptedRun` (other ranks go on)."""
        first = self._record(signum)
        try:
            submitit(signum, frame)
        except SystemExit:
            raise InterruptedRun(self.first or signal.Signals(signum).name) from None
        if first:
            self.first = None

    def _handlers(self) -> dict[signal.Signals, Handler]:
        handlers: dict[signal.Signals, Handler] = {signal.SIGTERM: self._on_sigterm}
        sigint = signal.getsignal(signal.SIGINT)
        if callable(sigint):  # a SIGINT ignored (a background job) stays ignored
            handlers[signal.SIGINT] = functools.partial(self._on_sigint, sigint)
        usr2 = signal.getsignal(signal.SIGUSR2)
        if callable(usr2) and "submitit" in getattr(usr2, "__module__", ""):
            handlers[signal.SIGUSR2] = functools.partial(self._on_requeue, usr2)
        return handlers

    @contextmanager
    def installed(self) -> Iterator[None]:
        """The handlers in place for the block (none outside the main thread), the previous ones after."""
        try:
            previous = {signum: signal.signal(signum, h) for signum, h in self._handlers().items()}
        except ValueError:  # not the main thread (a launcher's worker thread)
            yield
            return
        try:
            yield
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
            self.first = None

    def stop(self, error: BaseException, epoch: int | None = None) -> BaseException:
        """The :class:`InterruptedRun` that ``error`` means (also Lightning's ``SIGTERMException``, or its
        ``sys.exit(1)`` after a KeyboardInterrupt), named after the first signal; any other error as it is."""
        if isinstance(error, InterruptedRun):
            name = error.signal_name
        elif isinstance(error, SIGTERMException):
            name = "SIGTERM"
        elif isinstance(error, KeyboardInterrupt) or (
            isinstance(error, SystemExit) and isinstance(error.__context__, KeyboardInterrupt)
        ):
            name = "SIGINT"
        else:
            return error
        return InterruptedRun(self.first or name, epoch)


SIGNALS = StopSignals()
"""This process's stop signals: signal handlers belong to a process, so there is one."""
