"""A job folder's lock (lossvo.folder_lock): held while a process runs there, gone when it ends however."""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lossvo import folder_lock


def test_a_held_lock_is_seen_named_and_refused_to_another_taker(tmp_path: Path) -> None:
    assert folder_lock.in_use(tmp_path) is None  # no lock file: cannot tell
    with folder_lock.held(tmp_path, ", SLURM job 7") as guarded:
        assert guarded and (tmp_path / "run.lock").is_file()
        assert folder_lock.in_use(tmp_path) is True
        holder = folder_lock.holder(tmp_path)
        assert holder.startswith(f"pid {os.getpid()} on ") and holder.endswith(", SLURM job 7")
        with pytest.raises(folder_lock.FolderInUseError) as refused, folder_lock.held(tmp_path):
            pass
        assert str(refused.value) == (f"{tmp_path}: another process is running in this folder ({holder}): "
                                      "wait for it to end, or give this run another folder")  # fmt: skip
        assert folder_lock.holder(tmp_path) == holder  # the refused taker wrote nothing
    assert folder_lock.in_use(tmp_path) is False
    assert folder_lock.holder(tmp_path) == holder  # the last holder stays named


def test_the_lock_goes_with_a_killed_process(tmp_path: Path) -> None:
    """SIGKILL gives the process no chance to let go: the kernel does."""
    code = (
        "import sys, time; from pathlib import Path; from lossvo import folder_lock\n"
        "with folder_lock.held(Path(sys.argv[1])):\n    print('held', flush=True); time.sleep(600)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "held\n"
        assert folder_lock.in_use(tmp_path) is True
        assert folder_lock.holder(tmp_path).startswith(f"pid {proc.pid} on ")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    deadline = time.monotonic() + 10
    while folder_lock.in_use(tmp_path) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert folder_lock.in_use(tmp_path) is False


def test_a_file_system_without_locks_runs_unguarded_with_a_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def no_locks(fd: int, operation: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    with caplog.at_level(logging.WARNING, logger="lossvo"), folder_lock.held(tmp_path) as guarded:
        assert not guarded
        assert folder_lock.in_use(tmp_path) is None
    (record,) = caplog.records
    assert record.getMessage() == (
        f"{tmp_path / 'run.lock'}: the file system does not lock files (No locks available): nothing keeps "
        "a second process out of this folder"
    )


def test_other_lock_errors_are_raised(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def bad_descriptor(fd: int, operation: int) -> None:
        raise OSError(errno.EBADF, "Bad file descriptor")

    monkeypatch.setattr(fcntl, "flock", bad_descriptor)
    with pytest.raises(OSError, match="Bad file descriptor"), folder_lock.held(tmp_path):
        pass
