"""Command-line plumbing: the one error path of every entry point, and printing into a pipe that closes
early (``| head``). A user error (:func:`user_message`) ends a command in one line with exit status 2;
any other error keeps its traceback, and ``LOSSVO_FULL_ERROR=1`` keeps it for every error
(docs/bad-input.md).
"""

from __future__ import annotations

import argparse
import errno
import functools
import logging
import os
import re
import shutil
import sys
import traceback
import warnings
from collections.abc import Callable, Collection
from pathlib import Path
from typing import NoReturn, ParamSpec, TypeVar

from hydra.errors import (
    CompactHydraException,
    ConfigCompositionException,
    HydraException,
    InstantiationException,
    MissingConfigException,
    OverrideParseException,
)
from omegaconf.errors import OmegaConfBaseException, ValidationError

HYDRA_FLAGS = frozenset({
    "--help", "-h", "--hydra-help", "--version", "--cfg", "-c", "--resolve", "--package", "-p", "--run", "-r",
    "--multirun", "-m", "--shell-completion", "-sc", "--config-path", "-cp", "--config-name", "-cn",
    "--config-dir", "-cd", "--experimental-rerun", "--info", "-i",
})  # fmt: skip
"""The flags of a ``@hydra.main`` command line."""

FULL_ERROR = "LOSSVO_FULL_ERROR"


class UserError(Exception):
    """Bad input that lossvo refuses, in one line naming the key, file or line and what was expected (a
    ``ValueError`` is a programming error)."""


class JobFailedError(UserError):
    """A sweep job's user error, already printed by the job and recorded in its ``status.json``: the
    sweep's end names the job. ``args``: the job's label, the line and the sweep folder."""

    def __str__(self) -> str:
        return f"{self.args[0]}: {self.args[1]}"

    def summary(self) -> str:
        """The sweep's last line: which job failed, where its line is."""
        return (
            f"{self.args[0]} failed (its line is above and in its status.json); the sweep's other jobs "
            f"ran: python -m lossvo.report {self.args[2]} tables them"
        )


DISK_ERRORS = (
    errno.ENOSPC,
    errno.EDQUOT,
    errno.EROFS,
    errno.EACCES,
    errno.EPERM,
    errno.ENOENT,
    errno.ENOTDIR,
    errno.EISDIR,
)
"""OS errors that are the disk's or the user's, not lossvo's."""

_HYDRA_FULL_ERROR = "HYDRA_FULL_ERROR"
_P = ParamSpec("_P")
_R = TypeVar("_R")


def emit(text: str) -> None:
    """Print a line to stdout; once the reader has gone (``BrokenPipeError``) the rest is discarded."""
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's final flush then succeeds


def log_to_files(logger: logging.Logger, message: str) -> None:
    """An ERROR record of ``message`` in the log files ``logger`` writes to (Hydra's ``<job>.log``), not on
    its terminal handlers; a log file that cannot be written is passed over."""
    record = logger.makeRecord(logger.name, logging.ERROR, "(lossvo)", 0, message, (), None)
    raising, logging.raiseExceptions = logging.raiseExceptions, False  # a full disk: the line is on stderr
    try:
        current: logging.Logger | None = logger
        while current is not None:
            for handler in current.handlers:
                if isinstance(handler, logging.FileHandler) and record.levelno >= handler.level:
                    handler.handle(record)
            current = current.parent if current.propagate else None
    finally:
        logging.raiseExceptions = raising


def user_error_line(logger: logging.Logger, message: str) -> None:
    """A user error's one line: ``error: ...`` on stderr, and in the log files of ``logger``."""
    print(f"error: {message}", file=sys.stderr, flush=True)
    log_to_files(logger, message)


class OneLineParser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line on stderr (no usage block), exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def full_error() -> bool:
    """Whether ``LOSSVO_FULL_ERROR=1`` asks for full tracebacks instead of one-line errors."""
    return os.environ.get(FULL_ERROR) == "1"


def raise_if_full_error() -> None:
    """In an ``except`` block: with ``LOSSVO_FULL_ERROR=1``, re-raise the exception being handled."""
    if full_error() and sys.exc_info()[1] is not None:
        raise  # the exception the caller is handling


def exit_in_one_line(error: BaseException) -> NoReturn:
    """End the command on a user error where an exception would not (a Hydra callback): one line, exit
    status 2; with ``LOSSVO_FULL_ERROR=1`` its traceback, exit status 1."""
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
    """``<path>: <cause>`` for an OS error of :data:`DISK_ERRORS` (``folder`` where the error names no
    file); None for any other error."""
    if not isinstance(error, OSError) or error.errno not in DISK_ERRORS:
        return None
    cause = error.strerror or errno.errorcode.get(error.errno or 0, "OS error")
    where = error.filename or folder
    return f"{where}: {cause}" if where else cause


TYPE_REFUSALS = (
    r"Value '(?P<value>.*)' of type '(?P<given>\w+)' could not be converted to (?P<type>\w+)",
    r"Value '(?P<value>.*)' is not a valid (?P<type>bool) \(type (?P<given>\w+)\)",
    r"Value '(?P<value>.*)' \((?P<given>\w+)\) is incompatible with type hint '(?P<type>[^']+)'",
    r"Cannot assign (?P<given>\w+) to (?P<type>.+)",
    r"Invalid value assigned: \w+ is not a (?P<type>ListConfig), list or tuple",
    r"Merge error: (?P<given>\w+) is not a subclass of (?P<type>\w+)\. value: (?P<value>.*)",
)
"""OmegaConf's refusals of a value of the wrong type (first lines of its messages)."""

TYPE_NAMES = {"Integer": "an int", "int": "an int", "Float": "a float", "float": "a float",
              "Boolean": "a bool", "bool": "a bool", "String": "a string", "str": "a string",
              "ListConfig": "a list"}  # fmt: skip
"""OmegaConf's type names -> the expected type in a one-line error."""


def typed_value_message(
    error: OmegaConfBaseException, key: str | None = None, given: str | None = None
) -> str:
    """``<key>: expected an int, got 'abc'`` for OmegaConf's refusal of a value of the wrong type (``key``
    and ``given``, the value as typed, where the error lacks them); else the error's first line."""
    where = key or error.full_key
    text = first_line(error.msg)
    for pattern in TYPE_REFUSALS:
        match = re.match(pattern, text)
        if match:
            found = match.groupdict()
            kind = found["type"]
            expected = TYPE_NAMES.get(
                kind, "a mapping" if kind.startswith(("Dict", "Optional[Dict")) else kind
            )
            value = found.get("value")
            text_value = found.get("given") == "str" or (value is None and given is not None)
            value = given if value is None else value
            got = "" if value is None else f", got {value!r}" if text_value else f", got {value}"
            return f"{where}: expected {expected}{got}"
    return f"{where}: {text}"


def _typed_override(error: HydraException) -> str | None:
    """:func:`typed_value_message` of an override a structured config's type refuses, else None."""
    cause = error.__cause__
    match = re.match(r"Error merging override (?P<key>[^=]+)=(?P<value>.*)", first_line(error))
    if not (isinstance(error, ConfigCompositionException) and isinstance(cause, ValidationError) and match):
        return None
    return typed_value_message(cause, match.group("key").lstrip("+~"), match.group("value"))


def hydra_message(error: HydraException) -> str:
    """One line for a Hydra error (an unknown option listed with those there are, a bad override)."""
    text = str(error)
    typed = _typed_override(error)
    if typed is not None:
        return typed
    if isinstance(error, MissingConfigException) and error.options:
        return f"{first_line(text)} (available: {', '.join(error.options)})"
    if isinstance(error, OverrideParseException):
        return f"override {error.override!r}: {first_line(error.message)}"
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    head = lines[0].rstrip(".") if lines else type(error).__name__
    if error.__cause__ is not None:
        head = f"{head}: {first_line(error.__cause__)}"
    return "; ".join([head, *lines[1:]])


def _lightning_misconfiguration(error: BaseException) -> bool:
    """Whether an error is Lightning's ``MisconfigurationException``."""
    module = sys.modules.get("lightning.fabric.utilities.exceptions")
    return module is not None and isinstance(error, module.MisconfigurationException)


def _config_mismatch(target: str, cause: TypeError) -> bool:
    """Whether Hydra's ``_target_`` was called with keys its signature lacks or without ones it needs."""
    name = re.escape(target.rsplit(".", 1)[-1])
    mismatch = (
        r"(got an unexpected keyword argument|missing \d+ required (keyword-only |positional )?argument)"
    )
    return re.match(rf"{name}(\.__init__)?\(\) {mismatch}", str(cause)) is not None


def _instantiation_message(error: InstantiationException, folder: object) -> str | None:
    """One line, named by its key, for an object Hydra cannot instantiate because of its config (its
    ``_target_``, its keys, a user error); None where it fails otherwise."""
    text, cause = str(error), error.__cause__
    if isinstance(cause, OSError):
        return user_message(cause, folder)
    key = found.group(1).strip() if (found := re.search(r"^full_key:(.*)$", text, re.MULTILINE)) else ""
    target = match.group(1) if (match := re.search(r"target '([^']*)'", text)) else "?"
    if isinstance(cause, ImportError) and "Error locating target" in text:
        return f"{key}._target_: cannot import {target!r} ({first_line(cause.__cause__ or cause)})"
    mismatch = isinstance(cause, TypeError) and _config_mismatch(target, cause)
    if cause is None or not (mismatch or user_message(cause, folder)):
        return None
    reason = one_line(cause)
    return reason if not key or reason.startswith(key) else f"{key}: {reason}"


def user_message(error: BaseException, folder: object = None) -> str | None:
    """The one line of a user error, or None for an error that keeps its traceback: user errors are
    :class:`UserError`, Lightning's ``MisconfigurationException``, a disk error, Hydra's refusal of a
    config or override, and an instantiation that fails on one of these."""
    if isinstance(error, InstantiationException):
        return _instantiation_message(error, folder)
    if isinstance(error, CompactHydraException):  # before OSError: MissingConfigException is an IOError
        return hydra_message(error)
    if isinstance(error, OSError):
        return disk_error(error, folder)
    if isinstance(error, UserError) or _lightning_misconfiguration(error):
        return one_line(error)
    return None


def printed_one_line(error: BaseException, folder: object = None) -> bool:
    """For a user error, print ``error: ...`` on stderr and return True; else (or with
    ``LOSSVO_FULL_ERROR=1``) return False: the caller re-raises."""
    message = error.summary() if isinstance(error, JobFailedError) else user_message(error, folder)
    if message is None or full_error():
        return False
    print(f"error: {message}", file=sys.stderr)
    return True


def end_in_one_line(error: BaseException, folder: object = None) -> None:
    """:func:`printed_one_line`, then exit status 2 for a user error; nothing for any other error."""
    if printed_one_line(error, folder):
        raise SystemExit(2) from None


def one_line_main(main: Callable[_P, int]) -> Callable[_P, int]:
    """An argparse entry point (``main(argv) -> exit status``) whose user errors end in one line, status 2."""

    @functools.wraps(main)
    def wrapped(*args: _P.args, **kwargs: _P.kwargs) -> int:
        try:
            return main(*args, **kwargs)
        except Exception as e:
            if printed_one_line(e):
                return 2
            raise

    return wrapped


def _check_flags(argv: list[str]) -> None:
    """One line and exit status 2 for a flag Hydra does not know (instead of its usage block)."""
    for arg in argv:
        if arg.startswith("-") and arg.split("=", 1)[0] not in HYDRA_FLAGS:
            print(
                f"error: unrecognized option {arg} (--help lists the options; overrides are KEY=VALUE)",
                file=sys.stderr,
            )
            raise SystemExit(2)


def one_line_errors(hydra_main: Callable[_P, _R]) -> Callable[_P, _R]:
    """A ``@hydra.main`` entry point whose user errors end in one line with exit status 2 instead of
    Hydra's report; ``LOSSVO_FULL_ERROR=1`` or ``HYDRA_FULL_ERROR=1`` keeps every traceback."""

    @functools.wraps(hydra_main)
    def main(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        _check_flags(sys.argv[1:])
        given = os.environ.get(_HYDRA_FULL_ERROR)
        os.environ[_HYDRA_FULL_ERROR] = "1"  # Hydra raises its errors instead of printing them
        try:
            return hydra_main(*args, **kwargs)
        except Exception as e:
            if given != "1":
                end_in_one_line(e)
            raise
        finally:
            if given is None:
                os.environ.pop(_HYDRA_FULL_ERROR, None)
            else:
                os.environ[_HYDRA_FULL_ERROR] = given

    return main


def close_logs_in(folder: Path) -> None:
    """Close and detach the log files (Hydra's ``<job>.log``) kept in a folder about to be removed."""
    loggers = [logging.getLogger(), *logging.Logger.manager.loggerDict.values()]
    for logger in (item for item in loggers if isinstance(item, logging.Logger)):
        for handler in list(logger.handlers):
            if isinstance(handler, logging.FileHandler) and Path(handler.baseFilename).parent == folder:
                try:
                    handler.close()
                except OSError:  # a full disk: the lines it holds cannot be written
                    handler.stream = None
                logger.removeHandler(handler)


def remove_refused(folder: Path, made: Collection[str], keep_folder: bool = False) -> None:
    """Remove a refused command's output folder where it holds only the names in ``made`` (``.hydra``,
    ``eval.log``); with ``keep_folder`` (an empty folder the user gave) only its contents."""
    if not (folder.is_dir() and {p.name for p in folder.iterdir()} <= set(made)):
        return
    close_logs_in(folder)
    for path in folder.iterdir() if keep_folder else [folder]:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


LIGHTNING_HINTS = (
    r"The `srun` command is available on your system but is not used",
    r"The number of training batches .* is smaller than the logging interval",
    r"`isinstance\(treespec, LeafSpec\)` is deprecated",
)
"""Lightning's warnings that do not fit lossvo: ``srun`` (:mod:`lossvo.training.slurm` starts cluster
jobs), the logging interval (the curve's points are epoch means), Lightning's own call of a deprecated API."""

LIGHTNING_TIPS = ("Tip: For seamless cloud ",)
"""Lightning's advertising lines, dropped from its log."""

_RANK_ZERO_LOGGERS = ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero")


def _no_tips(record: logging.LogRecord) -> bool:
    return not any(tip in str(record.msg) for tip in LIGHTNING_TIPS)


def quiet_lightning() -> None:
    """Silence :data:`LIGHTNING_HINTS` and :data:`LIGHTNING_TIPS`; called by each entry point's job."""
    for hint in LIGHTNING_HINTS:
        warnings.filterwarnings("ignore", message=hint)
    for name in _RANK_ZERO_LOGGERS:
        logger = logging.getLogger(name)
        if _no_tips not in logger.filters:
            logger.addFilter(_no_tips)
