"""A run's life in its job folder: a stop during the final evaluation (and its history), a folder of another
config, full and read-only disks, short job folder names, the thread count, what a person reads (epochs
from 1)."""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
import yaml
from omegaconf import OmegaConf

from helpers import metrics_rows, scores_of, status_of, train_main
from lossvo.machine import machine
from lossvo.training import fitting, lifecycle
from lossvo.training.callbacks import EpochProgressBar
from lossvo.training.resolvers import MAX_NAME, path_safe
from test_train import tiny_overrides


def _args(tiny_kitti: Path, run: Path, *extra: str) -> list[str]:
    return [*tiny_overrides(tiny_kitti, run.parent / "cache"), f"hydra.run.dir={run}",
            "trainer.max_epochs=2", "trainer.deterministic=true", *extra]  # fmt: skip


def _error_lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if "[ERROR]" in line or line.startswith("error:")]


def _user_error(captured: pytest.CaptureResult[str]) -> str:
    """The one line of a user error: ``error: ...`` on stderr, nothing of it on stdout."""
    assert not _error_lines(captured.out), captured.out
    (line,) = _error_lines(captured.err)
    assert line.startswith("error: ")
    return line


@pytest.fixture(scope="module")
def uninterrupted(tiny_kitti: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A run of two epochs, start to finish, in process."""
    run = tmp_path_factory.mktemp("whole") / "run"
    monkeypatch = pytest.MonkeyPatch()
    assert train_main(_args(tiny_kitti, run), monkeypatch) == 0
    monkeypatch.undo()
    yield run


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_during_the_final_evaluation_resumes_the_evaluation(
    signum: int, uninterrupted: Path, tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = tmp_path / "run"
    evaluate_run = fitting.evaluate_run

    def stopped(*args, **kwargs):
        (run / "trajectories").mkdir(parents=True)
        (run / "trajectories" / "00.txt").write_text("half\n")
        os.kill(os.getpid(), signum)  # SIGINT raises KeyboardInterrupt here, SIGTERM lossvo's handler's
        raise AssertionError("the signal did not stop the evaluation")

    monkeypatch.setattr(fitting, "evaluate_run", stopped)
    # Python's own SIGINT handler, also where this process was started with SIGINT ignored (a background
    # job); Lightning leaves SIGINT ignored after a KeyboardInterrupt in a fit.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert train_main(_args(tiny_kitti, run), monkeypatch) == 128 + signum
    finally:
        signal.signal(signal.SIGINT, previous)
    status = status_of(run)
    assert status["status"] == "interrupted" and status["stage"] == "evaluation"
    assert status["signal"] == signal.Signals(signum).name and status["resume_from"].endswith("last.ckpt")
    written = metrics_rows(run)
    assert [r["epoch"] for r in written if r.get("val/score")] == ["0", "1"]

    monkeypatch.setattr(fitting, "evaluate_run", evaluate_run)
    assert train_main(_args(tiny_kitti, run), monkeypatch) == 0  # the same command
    assert metrics_rows(run) == written == metrics_rows(uninterrupted)  # nothing deleted, nothing repeated
    ours, theirs = status_of(run), status_of(uninterrupted)
    history = ours.pop("history")
    assert [e["event"] for e in history] == ["started", "stopped", "resumed", "completed"]
    stopped, resumed = history[1], history[2]  # training had completed: the evaluation resumed
    assert (stopped["stage"], resumed["stage"]) == ("evaluation", "evaluation") and "epoch" not in resumed
    assert resumed["from"] == status["resume_from"]
    assert history[0]["machine"] == resumed["machine"] == machine()
    assert [e["event"] for e in theirs.pop("history")] == ["started", "completed"]
    assert ours == theirs and ours["metrics"]["val/score"] > 0
    assert scores_of(run) == scores_of(uninterrupted)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:The dirpath has changed")  # a copied folder: Lightning notes the old one
def test_a_changed_config_in_a_completed_folder_is_refused(
    uninterrupted: Path, tmp_path: Path, tiny_kitti: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    run = tmp_path / "run"
    shutil.copytree(uninterrupted, run)
    before = {
        name: (run / name).read_bytes() for name in (".hydra/config.yaml", "status.json", "metrics.csv")
    }
    capsys.readouterr()
    args = _args(tiny_kitti, run, "loss=euler", "trainer.max_epochs=5")
    assert train_main(args, monkeypatch) == 2
    line = _user_error(capsys.readouterr())
    assert f"{run}: holds a run of another configuration (" in line
    assert "loss._target_" in line and "trainer.max_epochs" not in line
    assert {name: (run / name).read_bytes() for name in before} == before

    same = _args(tiny_kitti, run, "trainer.max_epochs=3", f"ckpt_path={run}/checkpoints/last.ckpt")
    assert train_main(same, monkeypatch) == 0  # extending a finished run
    assert [r["epoch"] for r in metrics_rows(run) if r.get("val/score")] == ["0", "1", "2"]
    assert status_of(run)["status"] == "completed"


def test_a_key_an_earlier_version_recorded_is_drift() -> None:
    """A config recorded by an earlier version holds keys this one does not have: a resume names them."""
    ours = OmegaConf.create(
        {"data": {"windows": {"seq_len": 2}, "flow": {"scale": 1.5}}, "model": {"hidden": 8}}
    )
    earlier = OmegaConf.merge(
        ours, {"data": {"flow": {"preset": "medium"}}, "model": {"intrinsics_layer": True}}
    )
    assert lifecycle.config_drift(earlier, ours) == ["data.flow.preset", "model.intrinsics_layer"]


@pytest.mark.slow
def test_resume_false_in_a_used_folder_is_refused(
    uninterrupted: Path, tmp_path: Path, tiny_kitti: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    run = tmp_path / "run"
    shutil.copytree(uninterrupted, run)
    assert train_main(_args(tiny_kitti, run, "resume=false"), monkeypatch) == 2
    line = _user_error(capsys.readouterr())
    assert "resume=false starts afresh only in a new folder" in line
    assert metrics_rows(run) == metrics_rows(uninterrupted)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("code", "cause"), [(errno.ENOSPC, "No space left on device"), (errno.EROFS, "Read-only file system")]
)
def test_a_disk_error_during_training_is_one_line(
    code: int, cause: str, tmp_path: Path, tiny_kitti: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    write_bytes = Path.write_bytes

    def refused(self: Path, data: bytes) -> int:
        if self.suffix == ".ckpt":
            raise OSError(code, os.strerror(code), str(self))
        return write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", refused)
    run = tmp_path / "run"
    assert train_main(_args(tiny_kitti, run), monkeypatch) == 2
    captured = capsys.readouterr()
    line = _user_error(captured)
    assert line.endswith(f"{run}/checkpoints/best.ckpt: {cause}") and "Traceback" not in captured.err
    status = status_of(run)
    assert status["status"] == "failed" and cause in status["error"]


def test_an_unwritable_run_folder_is_one_line(
    tmp_path: Path, tiny_kitti: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "readonly" / "run"
    mkdir = Path.mkdir

    def refused(self: Path, *args, **kwargs) -> None:
        if self == run:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))
        mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", refused)
    assert train_main(_args(tiny_kitti, run), monkeypatch) == 2
    captured = capsys.readouterr()
    assert captured.err.strip() == f"error: {run}: Read-only file system" and not run.exists()


def test_a_malformed_status_json_is_one_line_naming_it(
    tmp_path: Path, tiny_kitti: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "status.json").write_text('{"status": "completed", "metrics": []}')
    before = (run / "status.json").read_bytes()
    assert train_main(_args(tiny_kitti, run), monkeypatch) == 2
    captured = capsys.readouterr()
    line = _user_error(captured)
    assert line.endswith(f"{run}/status.json: metrics: expected an object of numbers, got []")
    assert "Traceback" not in captured.out
    assert sorted(p.name for p in run.iterdir()) == ["run.lock", "status.json", "train.log"]  # nothing else
    assert (run / "status.json").read_bytes() == before


def _mount(args: list[str]) -> None:
    result = subprocess.run(["mount", *args], capture_output=True, text=True)
    if result.returncode:
        pytest.skip(f"mount {' '.join(args)}: {result.stderr.strip() or 'not permitted'}")


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 384 KiB tmpfs: room for a run's config and logs, not for its checkpoints."""
    disk = tmp_path / "disk"
    disk.mkdir()
    _mount(["-t", "tmpfs", "-o", "size=384k", "tmpfs", str(disk)])
    yield disk
    subprocess.run(["umount", "--lazy", str(disk)], check=False)  # a log file of the run may be open


@pytest.fixture
def read_only(tmp_path: Path) -> Iterator[Path]:
    """A read-only bind mount of an empty folder."""
    source, target = tmp_path / "source", tmp_path / "readonly"
    source.mkdir()
    target.mkdir()
    _mount(["--bind", str(source), str(target)])
    _mount(["-o", "remount,bind,ro", str(target)])
    yield target
    subprocess.run(["umount", "--lazy", str(target)], check=False)


@pytest.mark.slow
def test_a_run_on_a_full_disk(
    small_disk: Path, tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    run = small_disk / "run"
    args = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), f"hydra.run.dir={run}"]
    assert train_main(args, monkeypatch) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    line = _user_error(captured)
    assert line.endswith(": No space left on device") and f"{run}/" in line
    status = status_of(run)
    assert status["status"] == "failed" and "No space left on device" in status["error"]


@pytest.mark.slow
def test_a_run_on_a_read_only_disk(
    read_only: Path, tiny_kitti: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    run = read_only / "run"
    args = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), f"hydra.run.dir={run}"]
    assert train_main(args, monkeypatch) == 2
    captured = capsys.readouterr()
    assert captured.err.strip() == f"error: {run}: Read-only file system" and not captured.out.strip()


def test_long_override_lists_give_short_stable_folder_names() -> None:
    overrides = "+".join(f"data.setting_{i}-{i / 7:.12f}" for i in range(20))
    name = path_safe(overrides)
    assert len(name) == MAX_NAME and name == path_safe(overrides) and name.startswith("data.setting_0-0.0")
    assert path_safe(overrides.replace("19-", "19-1")) != name  # another list, another name
    assert path_safe("loss=euler,seed=0") == "loss-euler+seed-0"  # short ones read as before


TWENTY = [
    "optimizer.lr=0.001",
    "optimizer.weight_decay=0.0",
    "trainer.log_every_n_steps=1",
    "trainer.gradient_clip_val=null",
    "trainer.check_val_every_n_epoch=1",
    "data.loader.num_workers=0",
    "data.windows.batch_size=4",
    "data.windows.seq_len=3",
    "data.frames.height=64",
    "data.frames.width=96",
    "model.hidden_size=16",
    "model.width_mult=0.0625",
    "weighting.c=100.0",
    "selection=score",
    "scheduler=cosine",
    "logger=csv",
    "trainer.max_epochs=1",
    "trainer.deterministic=true",
    "threads=1",
]
"""Nineteen overrides that leave the tiny experiment as it is, the thread count set; with the swept
``loss=euler,quat`` a job has twenty."""


@pytest.mark.slow
def test_a_sweep_of_twenty_overrides_has_short_names_and_numbered_jobs(
    run_tiny_sweep_here, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """A sweep of two jobs with twenty overrides each (in process): short folder names, ``job i/N``
    lines. (A sweep job's numbers against the same config run alone: ``test_sweep.py``.)"""
    sweep = tmp_path / "sweep"
    threads = torch.get_num_threads()
    try:  # in this process: threads=1 sets its thread count
        assert run_tiny_sweep_here(tmp_path / "s", sweep, [*TWENTY, "loss=euler,quat"]) == 0
    finally:
        torch.set_num_threads(threads)
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir())
    assert len(jobs) == 2 and all(len(j.name) <= 2 + MAX_NAME and "-h" in j.name for j in jobs)
    for job in jobs:
        assert len(yaml.safe_load((job / ".hydra" / "overrides.yaml").read_text())) == 21  # experiment too
        assert status_of(job)["status"] == "completed" and status_of(job)["threads"] == 1
    log = "".join(capfd.readouterr())
    assert "job 1/2 (" in log and "job 2/2 (" in log


@pytest.mark.slow
def test_epochs_are_counted_from_one_where_a_person_reads_them(uninterrupted: Path) -> None:
    log = (uninterrupted / "train.log").read_text()
    assert "epoch 1/2 (" in log and "epoch 2/2 (" in log and "val/score=" in log
    bar = EpochProgressBar()
    trainer = SimpleNamespace(max_epochs=2)
    bar._trainer = trainer  # type: ignore[attr-defined]
    assert bar._get_train_description(1) == "Epoch 2/2"  # the second of two
    assert [r["epoch"] for r in metrics_rows(uninterrupted) if r.get("val/score")] == ["0", "1"]  # Lightning
