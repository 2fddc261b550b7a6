"""A job folder's lock: ``run.lock``, held (an exclusive ``flock``) by the process that runs in the folder.

The kernel drops the lock when that process ends, however it ends, so the lock tells apart a run that is
alive from one whose ``status.json`` still says "running" because its process was killed (SIGKILL, the
out-of-memory killer, a lost node) before it could say so; and it keeps a second process (the same sweep
started twice) from training in a folder that is in use. Standard library only: ``fcntl.flock`` is all it
needs, and no lock library says who holds a lock. On NFS, Linux takes ``flock`` locks on the server, so
every client sees them; a file system that refuses locks (some Lustre mounts) leaves runs unguarded,
with a warning.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from lossvo.console import UserError

log = logging.getLogger("lossvo")

LOCK = "run.lock"


class FolderInUseError(UserError):
    """Another live process holds the folder's lock."""


@dataclass
class Held:
    """The lock as this process took it. ``guarded``: False where the file system refused the lock."""

    path: Path
    guarded: bool


def _holder(path: Path) -> str:
    """Who holds (or last held) a lock, as its holder wrote it: ``pid N on HOST since TIME``."""
    try:
        text = path.read_text().strip()
    except OSError:
        return "unknown process"
    return text or "unknown process"


def _describe(details: str) -> str:
    now = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return f"pid {os.getpid()} on {socket.gethostname()} since {now}{details}"


@contextmanager
def held(folder: Path, details: str = "") -> Iterator[Held]:
    """Hold ``folder/run.lock`` while the block runs; the file names the holder (pid, host, start time
    and ``details``, e.g. the SLURM job). The descriptor is not inherited across ``exec``.

    Raises:
        FolderInUseError: ``<folder>: another process is running in this folder (<holder>): ...``.
    """
    path = folder / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    try:
        guarded = _lock(fd, path, folder)
        if guarded:
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, (_describe(details) + "\n").encode(), 0)
            except OSError as e:  # a full disk: name the file
                raise OSError(e.errno, e.strerror, str(path)) from None
        yield Held(path, guarded)
    finally:
        os.close(fd)


def _lock(fd: int, path: Path, folder: Path) -> bool:
    """Take the lock without waiting: True when taken, False where the file system has no locks."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise FolderInUseError(
            f"{folder}: another process is running in this folder ({_holder(path)}): wait "
            "for it to end, or give this run another folder"
        ) from None
    except OSError as e:
        if e.errno not in (errno.ENOLCK, errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
            raise
        log.warning(
            "%s: the file system does not lock files (%s): nothing keeps a second process out of this folder",
            path,
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
    return _holder(folder / LOCK)
