"""One user-error path, as a user meets it on the real command lines: the line once, on stderr, also in the
run's log; a sweep's config checked before any folder is made; a sweep with a failed job fails; a disk full
at the very start names the file and leaves the folder as it was found."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from test_train import tiny_overrides

TRAIN = [sys.executable, "-m", "lossvo.train"]


def lossvo(argv: list[str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "LOSSVO_CACHE": str(tmp_path / "cache")}
    env.pop("LOSSVO_FULL_ERROR", None)
    return subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)


def error_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("error:") or "[ERROR]" in line]


def test_a_user_error_is_one_line_on_stderr_and_no_line_names_an_uncreated_folder(tmp_path: Path) -> None:
    run = tmp_path / "run"
    done = lossvo([*TRAIN, "data.frames.height=abc", f"hydra.run.dir={run}"], tmp_path)
    assert done.returncode == 2
    assert done.stderr == "error: data.frames.height: expected an int, got 'abc'\n"
    assert not error_lines(done.stdout) and str(run) not in done.stdout and not run.exists()


@pytest.mark.slow
def test_a_sweep_whose_every_job_fails_one_check_creates_nothing(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    done = lossvo([*TRAIN, "-m", "seed=0,1,2", "loss=euler,quat", "data.windows.seq_len=1",
                   f"hydra.sweep.dir={sweep}"], tmp_path)  # fmt: skip
    assert done.returncode == 2 and not sweep.exists()
    assert done.stderr == (
        "error: data.windows.seq_len: expected an integer >= 2 frames, got 1 (every one of the sweep's 6 "
        "jobs); nothing was created\n"
    )
    assert "Launching" not in done.stdout


@pytest.mark.slow
def test_a_sweep_with_a_failed_job_runs_the_others_and_fails(tiny_kitti: Path, tmp_path: Path) -> None:
    """seq_len=1 fails in its job (the check passes on the sweep's second job); seq_len=3 trains."""
    sweep = tmp_path / "sweep"
    args = [arg for arg in tiny_overrides(tiny_kitti, tmp_path / "cache") if "seq_len" not in arg]
    done = lossvo([*TRAIN, "-m", "data.windows.seq_len=1,3", *args, "trainer.max_epochs=1", "+evaluate=false",
                   "+trainer.limit_train_batches=1", "+trainer.limit_val_batches=1",
                   f"hydra.sweep.dir={sweep}"], tmp_path)  # fmt: skip
    assert done.returncode == 2, done.stdout + done.stderr
    line = "data.windows.seq_len: expected an integer >= 2 frames, got 1"
    failed, completed = sorted(p for p in sweep.iterdir() if p.is_dir())
    assert json.loads((failed / "status.json").read_text())["error"] == line
    assert json.loads((completed / "status.json").read_text())["status"] == "completed"
    label = "job 1/2 (data.windows.seq_len=1 data=kitti "  # the swept key first, then the others
    logged = [entry for entry in (failed / "train.log").read_text().splitlines() if "[ERROR]" in entry]
    assert len(logged) == 1 and f"[ERROR] - {label}" in logged[0] and logged[0].endswith(f"): {line}")
    errors = error_lines(done.stderr)
    assert errors[0].startswith(f"error: {label}") and errors[0].endswith(f"): {line}")
    assert errors[-1].startswith(f"error: {label}") and "failed (its line is above" in errors[-1]
    assert f"python -m lossvo.report {sweep} tables them" in errors[-1]
    assert len(errors) == 2 and not error_lines(done.stdout)


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[Path]:
    """A 64 KiB tmpfs, filled."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)],
                             capture_output=True, text=True)  # fmt: skip
    if mounted.returncode:
        pytest.skip(f"mount: {mounted.stderr.strip() or 'not permitted'}")
    subprocess.run(["dd", "if=/dev/zero", f"of={disk / 'filler'}", "bs=1k", "count=128"], capture_output=True)
    yield disk
    subprocess.run(["umount", "--lazy", str(disk)], check=False)


@pytest.mark.slow
def test_a_full_disk_at_the_start_names_the_file_and_leaves_nothing(
    full_disk: Path, tiny_kitti: Path, tmp_path: Path
) -> None:
    base = tiny_overrides(tiny_kitti, tmp_path / "cache")
    run, sweep = full_disk / "run", full_disk / "sweep"
    done = lossvo([*TRAIN, *base, f"hydra.run.dir={run}"], tmp_path)
    assert (done.returncode, done.stderr) == (2, f"error: {run}/run.lock: No space left on device\n")
    done = lossvo([*TRAIN, "-m", "seed=0,1", *base, f"hydra.sweep.dir={sweep}"], tmp_path)
    assert (done.returncode, done.stderr) == (2, f"error: {sweep}: No space left on device\n")
    trained = tmp_path / "trained"
    done = lossvo([*TRAIN, *base, f"hydra.run.dir={trained}", "trainer.max_epochs=1", "+evaluate=false",
                   "+trainer.limit_train_batches=1", "+trainer.limit_val_batches=1"], tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    evaluation = full_disk / "eval"
    done = lossvo([sys.executable, "-m", "lossvo.eval", f"ckpt_path={trained / 'checkpoints' / 'best.ckpt'}",
                   f"hydra.run.dir={evaluation}"], tmp_path)  # fmt: skip
    assert (done.returncode, done.stderr) == (2, f"error: {evaluation}: No space left on device\n")
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]
