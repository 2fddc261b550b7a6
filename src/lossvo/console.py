"""Command-line plumbing: one-line errors (argument parsers, Hydra entry points), and printing a result
also into a pipe that closes early (``| head``).

A user error (a bad argument, override, config value or input file) ends a command in one line naming
the key, file or line and what was expected, with exit status 2 and no traceback. ``LOSSVO_FULL_ERROR=1``
in the environment shows the full traceback instead, as ``HYDRA_FULL_ERROR=1`` does for Hydra.
"""

from __future__ import annotations

import argparse
import errno
import functools
import os
import re
import sys
import traceback
from collections.abc import Callable
from typing import NoReturn, ParamSpec, TypeVar

from hydra._internal.utils import get_args_parser  # the parser @hydra.main reads the command line with
from hydra.errors import (
    CompactHydraException,
    HydraException,
    InstantiationException,
    MissingConfigException,
    OverrideParseException,
)

FULL_ERROR = "LOSSVO_FULL_ERROR"
"""The environment variable that, set to 1, turns one-line user errors into full tracebacks."""

USER_ERRORS = (ValueError, TypeError, ImportError)
"""Errors a constructor raises on a config value it refuses (or a ``_target_`` that does not import)."""

DISK_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM)
"""OS errors that are the disk's or the user's (full, read-only, not permitted), not lossvo's."""

_HYDRA_FULL_ERROR = "HYDRA_FULL_ERROR"
_P = ParamSpec("_P")
_R = TypeVar("_R")


def emit(text: str) -> None:
    """Print text and a newline to stdout. When the reader has gone (``BrokenPipeError``), the rest of
    the output is discarded quietly, as command-line tools do, instead of ending in a traceback."""
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's final flush then succeeds


class OneLineParser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line on stderr (no usage block), exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def full_error() -> bool:
    """Whether ``LOSSVO_FULL_ERROR=1`` asks for full tracebacks instead of one-line errors."""
    return os.environ.get(FULL_ERROR) == "1"


def raise_if_full_error() -> None:
    """Called in an ``except`` block before printing a one-line error: with ``LOSSVO_FULL_ERROR=1``,
    re-raise the exception being handled, so that it ends in its full traceback."""
    if full_error() and sys.exc_info()[1] is not None:
        raise  # the exception the caller is handling


def exit_in_one_line(error: BaseException) -> NoReturn:
    """End the command on a user error found where an exception would not end it (a Hydra callback: Hydra
    turns its exceptions into warnings): ``error: ...`` on stderr, exit status 2; with
    ``LOSSVO_FULL_ERROR=1`` its traceback, exit status 1."""
    if full_error():
        traceback.print_exception(error)
        raise SystemExit(1) from None
    print(f"error: {error}", file=sys.stderr)
    raise SystemExit(2) from None


def first_line(text: object) -> str:
    """The first non-empty line of a message, stripped."""
    return next((line.strip() for line in str(text).splitlines() if line.strip()), "")


def one_line(text: object) -> str:
    """A message on one line: its non-empty lines, stripped, joined by "; "."""
    return "; ".join(line.strip() for line in str(text).splitlines() if line.strip())


def disk_error(error: BaseException, folder: object = None) -> str | None:
    """One line for an OS error of :data:`DISK_ERRORS`, naming the path and the cause
    (``/data/run/status.json: No space left on device``), or ``folder`` where the error names no file;
    None for any other error."""
    if not isinstance(error, OSError) or error.errno not in DISK_ERRORS:
        return None
    cause = error.strerror or errno.errorcode.get(error.errno or 0, "OS error")
    where = error.filename or folder
    return f"{where}: {cause}" if where else cause


def hydra_message(error: HydraException) -> str:
    """One line for a Hydra error: an unknown config group option with the options there are, an
    override of a key the config lacks, an override that does not parse, an object that cannot be
    instantiated from its config (named by its key)."""
    text = str(error)
    if isinstance(error, MissingConfigException) and error.options:
        return f"{first_line(text)} (available: {', '.join(error.options)})"
    if isinstance(error, OverrideParseException):
        return f"override {error.override!r}: {first_line(error.message)}"
    if isinstance(error, InstantiationException):
        key = next((line.split(":", 1)[1].strip() for line in text.splitlines()
                    if line.startswith("full_key:")), "")  # fmt: skip
        cause = error.__cause__
        if isinstance(cause, ImportError):  # the _target_ does not import
            target = match.group(1) if (match := re.search(r"target '([^']*)'", text)) else "?"
            return f"{key}._target_: cannot import {target!r} ({first_line(cause.__cause__ or cause)})"
        reason = one_line(cause) if cause is not None else first_line(text)
        return reason if not key or reason.startswith(key) else f"{key}: {reason}"
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    head = lines[0].rstrip(".") if lines else type(error).__name__
    if error.__cause__ is not None:
        head = f"{head}: {first_line(error.__cause__)}"
    return "; ".join([head, *lines[1:]])


def _user_error(error: Exception) -> bool:
    """Whether a Hydra error is the user's: a config that does not compose, an override that does not
    parse, an object whose config its class refuses."""
    if isinstance(error, InstantiationException):
        return isinstance(error.__cause__, USER_ERRORS)
    return isinstance(error, CompactHydraException)


def _check_flags(argv: list[str]) -> None:
    """One line and exit status 2 for a command-line flag that Hydra's own parser does not know (it
    would print its usage block)."""
    known = {option for action in get_args_parser()._actions for option in action.option_strings}
    for arg in argv:
        if arg.startswith("-") and arg.split("=", 1)[0] not in known:
            print(f"error: unrecognized option {arg} (--help lists the options; overrides are KEY=VALUE)",
                  file=sys.stderr)  # fmt: skip
            raise SystemExit(2)


def one_line_errors(hydra_main: Callable[_P, _R]) -> Callable[_P, _R]:
    """A ``@hydra.main`` entry point whose config errors (an unknown config group option, an override
    of a key the config lacks, a malformed override) and disk errors (:func:`disk_error`) end in one
    line on stderr with exit status 2, instead of Hydra's multi-line report with exit status 1. Errors
    that are not the user's keep their traceback; ``LOSSVO_FULL_ERROR=1`` (or ``HYDRA_FULL_ERROR=1``)
    keeps it for every error."""

    @functools.wraps(hydra_main)
    def main(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        _check_flags(sys.argv[1:])
        given = os.environ.get(_HYDRA_FULL_ERROR)
        os.environ[_HYDRA_FULL_ERROR] = "1"  # Hydra raises its errors instead of printing them
        try:
            return hydra_main(*args, **kwargs)
        except HydraException as e:
            if full_error() or given == "1" or not _user_error(e):
                raise
            print(f"error: {hydra_message(e)}", file=sys.stderr)
            raise SystemExit(2) from None
        except OSError as e:  # e.g. Hydra creating an output folder where it may not
            if full_error() or given == "1" or disk_error(e) is None:
                raise
            print(f"error: {disk_error(e)}", file=sys.stderr)
            raise SystemExit(2) from None
        finally:
            if given is None:
                os.environ.pop(_HYDRA_FULL_ERROR, None)
            else:
                os.environ[_HYDRA_FULL_ERROR] = given

    return main
