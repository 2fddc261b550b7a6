"""Stopping a run on a signal: which signal stopped it, and the one exception that says so.

Three signals stop a run: SIGINT (Ctrl-C), SIGTERM (``kill``, SLURM's preemption or time limit) and SIGUSR2
(submitit's, before the time limit or on preemption). While a run runs, :data:`SIGNALS` handles them
(:meth:`StopSignals.installed`) and records the first; :meth:`StopSignals.stop` turns each way a stop ends the
code it interrupts into an :class:`InterruptedRun` named after that first signal (a later one, such as SLURM's
SIGTERM after submitit's requeue, is not the cause). During a fit Lightning owns SIGTERM and ends the fit at
its next check, calling this handler, which only records the signal; outside a fit the SIGTERM handler raises
:class:`InterruptedRun` at once. What a stopped run leaves: docs/training.md.
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from lightning.pytorch.utilities.exceptions import SIGTERMException

Handler = Callable[[int, Any], Any]


class InterruptedRun(BaseException):
    """A run stopped by a signal. A BaseException, as KeyboardInterrupt is: raised from a signal handler,
    it can arise inside any code, and a library's ``except Exception`` must not swallow it.

    Args:
        signal_name: ``"SIGINT"``, ``"SIGTERM"`` or ``"SIGUSR2"``.
        epoch: the epoch that was running, counted from 1; None when the stop came outside training.
    """

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


def _is_submitit(handler: Any) -> bool:
    return callable(handler) and "submitit" in getattr(handler, "__module__", "")


class StopSignals:
    """The signals that stop a run, and the first of them to come (:attr:`first`, a name such as
    ``"SIGTERM"``; None before any)."""

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

    def _on_sigint(self, previous: Handler) -> Handler:
        """SIGINT: recorded, then the handler it had (Python's raises KeyboardInterrupt)."""

        def handler(signum: int, frame: Any) -> Any:
            self._record(signum)
            return previous(signum, frame)

        return handler

    def _on_requeue(self, submitit: Handler) -> Handler:
        """Submitit's requeue signal: submitit requeues the job and exits, and the exit becomes an
        :class:`InterruptedRun`; a process it does not exit (a DDP rank above 0) goes on, unstopped."""

        def handler(signum: int, frame: Any) -> None:
            first = self._record(signum)
            try:
                submitit(signum, frame)
            except SystemExit:
                raise InterruptedRun(self.first or signal.Signals(signum).name) from None
            if first:
                self.first = None

        return handler

    def _handlers(self) -> dict[signal.Signals, Handler]:
        handlers: dict[signal.Signals, Handler] = {signal.SIGTERM: self._on_sigterm}
        sigint = signal.getsignal(signal.SIGINT)
        if callable(sigint):  # a SIGINT ignored (a background job) stays ignored
            handlers[signal.SIGINT] = self._on_sigint(sigint)
        usr2 = signal.getsignal(signal.SIGUSR2)
        if _is_submitit(usr2):
            assert callable(usr2)
            handlers[signal.SIGUSR2] = self._on_requeue(usr2)
        return handlers

    @contextmanager
    def installed(self) -> Iterator[None]:
        """The handlers in place for the block, the handlers before them restored after it (in a thread
        other than the main one, where a signal cannot be handled, nothing is installed)."""
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
        """The :class:`InterruptedRun` that ``error`` means, named after the first signal, with ``epoch``
        (the epoch it interrupted, from 1; None outside training); any other error as it is.

        A stop ends a fit as an :class:`InterruptedRun` (submitit's exit, SIGTERM outside a fit), as
        Lightning's ``SIGTERMException``, or after a KeyboardInterrupt as Lightning's ``sys.exit(1)``.
        """
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
