"""Output folders lossvo did not make: a run, a sweep or an evaluation given one is refused in one line
before anything is written, and the folder is left exactly as it was; an empty folder the user made is used
and, on a refusal, emptied again (never removed). The real command lines, as a user types them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lossvo.output_folders import check_output_folder, existed, was_empty


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder``, relative path -> bytes."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def lossvo(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "LOSSVO_FULL_ERROR"}
    return subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, cwd=cwd, env=env,
                          timeout=300)  # fmt: skip


def test_a_folder_holding_the_users_files_is_refused_and_left_as_it_was(tmp_path: Path) -> None:
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "train.log").write_text("my own log\n")
    (notes / "ideas.md").write_text("# ideas\n")
    before = snapshot(notes)
    for argv in (["lossvo.train", "data.windows.seq_len=1", f"hydra.run.dir={notes}"],
                 ["lossvo.train", "-m", "loss=euler,quat", f"hydra.sweep.dir={notes}"],
                 ["lossvo.eval", "ckpt_path=nowhere.ckpt", f"hydra.run.dir={notes}"]):  # fmt: skip
        done = lossvo(*argv, cwd=tmp_path)
        key = "hydra.sweep.dir" if "-m" in argv else "hydra.run.dir"
        assert done.returncode == 2 and done.stderr.startswith(
            f"error: {key}: {notes} holds files that lossvo"
        )
        assert done.stderr.count("\n") == 1 and "run folder" not in done.stdout
        assert snapshot(notes) == before  # no run.lock, no train.log line, nothing removed


def test_an_empty_folder_of_the_users_is_emptied_again_on_a_refusal_never_removed(tmp_path: Path) -> None:
    for argv in (["lossvo.train", "data.windows.seq_len=1"], ["lossvo.eval", "ckpt_path=nowhere.ckpt"]):
        folder = tmp_path / argv[0]
        folder.mkdir()
        done = lossvo(*argv, f"hydra.run.dir={folder}", cwd=tmp_path)
        assert done.returncode == 2
        assert folder.is_dir() and list(folder.iterdir()) == []
    new = tmp_path / "new"
    assert (
        lossvo("lossvo.train", "data.windows.seq_len=1", f"hydra.run.dir={new}", cwd=tmp_path).returncode == 2
    )
    assert not new.exists()  # a folder the refused run created is removed


def test_which_folders_are_lossvos(tmp_path: Path) -> None:
    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    (run / ".hydra" / "config.yaml").write_text("seed: 0\n")
    check_output_folder(run, "hydra.run.dir")  # a run of lossvo's: resumed in place
    assert existed(run) and not was_empty(run)
    sweep = tmp_path / "sweep"
    (sweep / "0_loss-euler" / ".hydra").mkdir(parents=True)
    (sweep / "0_loss-euler" / ".hydra" / "config.yaml").write_text("seed: 0\n")
    check_output_folder(sweep, "hydra.sweep.dir", sweep=True)
    with pytest.raises(Exception, match="holds files that lossvo did not write"):
        check_output_folder(sweep, "hydra.run.dir")  # a sweep folder is no run folder
    check_output_folder(tmp_path / "absent", "hydra.run.dir")
    assert not existed(tmp_path / "absent") and was_empty(tmp_path / "absent")
