"""Atomic writes: whole files or none, with the permissions the umask gives."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from lossvo import atomic


def test_written_file_has_the_umask_permissions(tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    atomic.write_text_atomic(path, "{}")
    assert path.read_text() == "{}"
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~atomic.UMASK
    plain = tmp_path / "plain.txt"
    plain.write_text("x")  # what open() gives a new file under the same umask
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)


def test_an_error_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "status.json"
    path.write_text("old")
    with pytest.raises(RuntimeError), atomic.atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["status.json"]
