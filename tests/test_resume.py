"""Runs that survive: last.ckpt every epoch, resume equals uninterrupted, metrics.csv continuity,
extending a finished run, atomic checkpoints on a full disk, SIGINT / SIGTERM and resuming by itself."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import lightning as L
import pytest
import torch

from helpers import fit, metrics_rows, train_main
from lossvo.report.jobs import load_job
from lossvo.training import checkpoints
from lossvo.training.stopping import InterruptedRun
from test_train import compose_train, tiny_overrides

REPO = Path(__file__).resolve().parents[1]


class InterruptAtEpoch(L.Callback):
    """Raises KeyboardInterrupt (what SIGINT raises) when ``epoch`` starts: the epochs before it are
    complete and checkpointed."""

    def __init__(self, epoch: int) -> None:
        self.epoch = epoch

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.current_epoch == self.epoch:
            raise KeyboardInterrupt


@pytest.fixture
def restore_sigint():
    """Lightning ignores SIGINT after a KeyboardInterrupt; give pytest its handler back."""
    yield
    signal.signal(signal.SIGINT, signal.default_int_handler)


MIRROR_AND_ROLL = (
    "data.transforms=[{_target_:lossvo.data.transforms.Mirror,p:0.5},"
    "{_target_:lossvo.data.transforms.Roll,p:0.5,max_rad:0.01}]"
)


def _overrides(tiny_kitti: Path, cache: Path, *extra: str) -> list[str]:
    return [*tiny_overrides(tiny_kitti, cache), "loss=chordal", "trainer.deterministic=true",
            MIRROR_AND_ROLL, *extra]  # fmt: skip


def _values(run: Path, key: str) -> list[tuple[str, str, float]]:
    """(epoch, step, value) of every row logging ``key``, in file order."""
    return [(r.get("epoch", ""), r["step"], float(r[key])) for r in metrics_rows(run) if r.get(key)]


def _weights(run: Path) -> dict[str, torch.Tensor]:
    return checkpoints.read(run / "checkpoints" / "last.ckpt")["state_dict"]


@pytest.mark.slow
def test_resume_equals_uninterrupted(tiny_kitti: Path, tmp_path: Path, restore_sigint) -> None:
    cache = tmp_path / "cache"
    whole = tmp_path / "whole"
    fit(compose_train(_overrides(tiny_kitti, cache, "trainer.max_epochs=3"), whole))

    parts = tmp_path / "parts"
    stop = ["+callbacks.stop._target_=test_resume.InterruptAtEpoch", "+callbacks.stop.epoch=1"]
    with pytest.raises(InterruptedRun, match="SIGINT during epoch 2"):  # counted from 1
        fit(compose_train(_overrides(tiny_kitti, cache, "trainer.max_epochs=3", *stop), parts))
    assert checkpoints.read(parts / "checkpoints" / "last.ckpt")["epoch"] == 0
    assert sorted(p.name for p in (parts / "checkpoints").iterdir()) == ["best.ckpt", "last.ckpt"]
    resumed = _overrides(
        tiny_kitti, cache, "trainer.max_epochs=3", f"ckpt_path={parts}/checkpoints/last.ckpt"
    )
    fit(compose_train(resumed, parts))

    ours, theirs = _weights(parts), _weights(whole)
    for name in theirs:
        torch.testing.assert_close(ours[name], theirs[name], rtol=0, atol=0, msg=name)
    for key in ("train/loss", "val/score", "val/rpe_trans_rmse", "lr-Adam"):
        assert _values(parts, key) == _values(whole, key), key
    epochs = [int(float(r["epoch"])) for r in metrics_rows(parts) if r.get("val/score")]
    assert epochs == [0, 1, 2]  # every epoch once, across the resume


@pytest.mark.slow
def test_extending_a_finished_run_continues_the_schedule(tiny_kitti: Path, tmp_path: Path) -> None:
    cache, run = tmp_path / "cache", tmp_path / "run"
    fit(compose_train(_overrides(tiny_kitti, cache, "trainer.max_epochs=2"), run))
    before = _weights(run)
    longer = _overrides(tiny_kitti, cache, "trainer.max_epochs=3", f"ckpt_path={run}/checkpoints/last.ckpt")
    fit(compose_train(longer, run))
    lr = [value for _, _, value in _values(run, "lr-Adam")]
    assert len(lr) == 3
    # cosine over 3 epochs at epoch 2: lr0 (1 + cos(2 pi / 3)) / 2 = lr0 / 4, not the old schedule's 0
    assert lr[2] == pytest.approx(lr[0] / 4, rel=1e-6)
    after = _weights(run)
    assert any(not torch.equal(before[k], after[k]) for k in before if before[k].is_floating_point())


def test_a_full_disk_keeps_the_previous_checkpoint(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    io = checkpoints.AtomicCheckpointIO()
    path = tmp_path / "last.ckpt"
    io.save_checkpoint({"epoch": 1, "weights": torch.ones(3)}, path)

    write_bytes = Path.write_bytes

    def full_disk(self: Path, data: bytes) -> int:
        write_bytes(self, bytes(data)[:10])  # half a checkpoint, then the disk is full
        raise OSError(errno.ENOSPC, "No space left on device", str(self))

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    with pytest.raises(OSError, match="No space left"):
        io.save_checkpoint({"epoch": 2, "weights": torch.zeros(3)}, path)
    assert torch.load(path)["epoch"] == 1  # the previous one, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.ckpt"]  # no partial file left


def _args(tiny_kitti: Path, base: Path, *extra: str) -> list[str]:
    return [*tiny_overrides(tiny_kitti, base / "cache"), f"hydra.run.dir={base / 'run'}", *extra]


def _start(tiny_kitti: Path, base: Path, *extra: str) -> subprocess.Popen:
    command = [sys.executable, "-m", "lossvo.train", *_args(tiny_kitti, base, *extra)]
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    return subprocess.Popen(command, cwd=base, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signals_leave_an_interrupted_job_that_resumes_by_itself(
    tiny_kitti: Path, tmp_path: Path, signum: int, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    proc = _start(tiny_kitti, tmp_path, "trainer.max_epochs=200")
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    deadline = time.monotonic() + 240
    while not last.is_file() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert proc.poll() is None, proc.communicate()[0][-3000:]
    proc.send_signal(signum)
    output = proc.communicate(timeout=120)[0]
    assert proc.returncode == 128 + signum, output[-3000:]
    status = json.loads((tmp_path / "run" / "status.json").read_text())
    name = signal.Signals(signum).name
    assert status["status"] == "interrupted" and status["signal"] == name
    assert status["resume_from"] == str(last)
    done = checkpoints.read(last)["epoch"]  # loadable
    assert status["epoch"] >= done + 1  # counted from 1; the signal may come between two epochs
    saved = sorted(p.name for p in last.parent.iterdir())
    assert saved == ["best.ckpt", "last.ckpt"]  # a resume continues from last.ckpt: nothing else is saved
    assert "Traceback" not in output and f"interrupted by {name}" in output
    if signum != signal.SIGTERM:
        return
    # The same command, in process: the same job folder resumes by itself; a checkpoint of a stop that an
    # earlier lossvo saved there (never read) goes.
    (last.parent / "interrupted.ckpt").write_bytes(last.read_bytes())
    assert train_main(_args(tiny_kitti, tmp_path, f"trainer.max_epochs={done + 2}"), monkeypatch) == 0
    assert f"(resuming from {last})" in capsys.readouterr().out
    status = json.loads((tmp_path / "run" / "status.json").read_text())
    assert status["status"] == "completed" and sorted(p.name for p in last.parent.iterdir()) == saved
    resumed = status["history"][-2]
    assert (resumed["event"], resumed["epoch"], resumed["from"]) == ("resumed", done + 2, str(last))
    epochs = [int(float(r["epoch"])) for r in metrics_rows(tmp_path / "run") if r.get("val/score")]
    assert epochs == list(range(done + 2))  # every epoch once


@pytest.mark.slow
def test_a_second_process_is_refused_and_a_killed_run_is_told_and_resumes(
    tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """While a run trains, the same command in its folder ends in one line (exit status 2) and leaves the
    folder as it was. SIGKILL leaves status.json saying "running": the report tells it killed (nothing
    holds run.lock), and the same command resumes it, its history saying so."""
    run = tmp_path / "run"
    proc = _start(tiny_kitti, tmp_path, "trainer.max_epochs=200")
    last = run / "checkpoints" / "last.ckpt"
    deadline = time.monotonic() + 240
    while not last.is_file() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert proc.poll() is None, proc.communicate()[0][-3000:]
    second = _start(tiny_kitti, tmp_path, "trainer.max_epochs=200")
    output = second.communicate(timeout=240)[0]
    assert second.returncode == 2, output[-3000:]
    (line,) = [line for line in output.splitlines() if line.startswith("error:")]
    assert f"{run}: another process is running in this folder (pid {proc.pid} on " in line, line
    assert "Traceback" not in output
    assert proc.poll() is None  # the first run trains on
    proc.kill()
    proc.communicate(timeout=60)
    status = json.loads((run / "status.json").read_text())
    assert status["status"] == "running" and [e["event"] for e in status["history"]] == ["started"]
    job = load_job(run)
    assert job.skip is not None and job.skip.startswith(
        f"killed: status.json says running but no process holds run.lock (last held by pid {proc.pid} on "
    ), job.skip
    done = checkpoints.read(last)["epoch"]
    capsys.readouterr()
    assert train_main(_args(tiny_kitti, tmp_path, f"trainer.max_epochs={done + 2}"), monkeypatch) == 0
    assert f"(resuming from {last})" in capsys.readouterr().out
    history = json.loads((run / "status.json").read_text())["history"]
    assert [e["event"] for e in history] == ["started", "killed", "resumed", "completed"]
    assert history[0]["time"] <= history[1]["time"] <= history[2]["time"]
