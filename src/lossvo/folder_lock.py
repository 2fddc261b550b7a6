"""A job folder's lock: ``run.lock``, an exclusive ``flock`` held by the process that runs in the folder.

The kernel drops it when that process ends, however it ends: a killed run is told from a live one, and a
second process is kept out (docs/training.md). ``fcntl`` by hand: no lock library says who holds a lock.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

from lossvo.console import UserError

log = logging.getLogger("lossvo")

LOCK = "run.lock"


class FolderInUseError(UserError):
    """Another live process holds the folder's lock."""


@contextmanager
def held(folder: Path, details: str = "") -> Iterator[bool]:
    """Hold ``folder/run.lock`` while the block runs (:class:`FolderInUseError` where another process
    holds it), giving whether it guards the folder (False where the file system has no locks); the file
    names the holder: pid, host, start time and ``details`` (e.g. the SLURM job)."""
    path = folder / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    try:
        guarded = _lock(fd, folder)
        if guarded:
            now = datetime.now(timezone.utc).isoformat(timespec="seconds")
            try:
                os.ftruncate(fd, 0)
                os.pwrite(
                    fd, f"pid {os.getpid()} on {socket.gethostname()} since {now}{details}\n".encode(), 0
                )
            except OSError as e:  # a full disk: name the file
                raise OSError(e.errno, e.strerror, str(path)) from None
        yield guarded
    finally:
        os.close(fd)


def _lock(fd: int, folder: Path) -> bool:
    """Take the lock without waiting: True when taken, False where the file system has no locks."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise FolderInUseError(
            f"{folder}: another process is running in this folder ({holder(folder)}): wait "
            "for it to end, or give this run another folder"
        ) from None
    except OSError as e:
        if e.errno not in (errno.ENOLCK, errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
            raise
        log.warning(
            "%s: the file system does not lock files (%s): nothing keeps a second process out of this folder",
            folder / LOCK,
            e.strerror,
        )
        return False
    return True


def in_use(folder: Path) -> bool | None:
    """Whether a live process holds ``folder/run.lock``: None where there is no lock file (a folder
    written without one, or never started) or the file system cannot tell."""
    try:
        fd = os.open(folder / LOCK, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return None
    finally:
        os.close(fd)
    return False


def holder(folder: Path) -> str:
    """What the lock's (last) holder wrote: ``pid N on HOST since TIME``."""
    try:
        return (folder / LOCK).read_text().strip() or "unknown process"
    except OSError:
        return "unknown process"
