"""The job folder's contract: status.json and metrics.csv typed, written atomically, read back; a malformed
file is one line naming it; metrics.csv appended byte for byte as Lightning's logger writes it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from lightning.pytorch.loggers.csv_logs import ExperimentWriter

from lossvo.evaluation.job_folder import (
    STATUS_SCHEMA_VERSION,
    Event,
    JobFolderError,
    MetricsTable,
    Status,
    append_metrics,
    read_metrics,
    read_status,
    write_metrics,
    write_status,
)
from lossvo.report.jobs import load_job
from lossvo.training.loggers import AppendingWriter, continue_history


def test_a_status_reads_back_as_written(tmp_path: Path) -> None:
    history = (Event("started", "2026-01-01T00:00:00+00:00", slurm_job="12_0", slurm_restarts=0),
               Event("stopped", "2026-01-01T00:05:00+00:00", signal="SIGUSR2", epoch=3),
               Event("resumed", "2026-01-01T00:09:00+00:00", epoch=3, source="/x/last.ckpt"))  # fmt: skip
    status = Status("interrupted", history, threads=4, signal="SIGUSR2", epoch=3)
    write_status(tmp_path, status)
    assert read_status(tmp_path) == status
    obj = json.loads((tmp_path / "status.json").read_text())
    assert list(obj) == ["schema_version", "status", "threads", "signal", "epoch", "resume_from", "history"]
    assert obj["schema_version"] == STATUS_SCHEMA_VERSION
    assert obj["resume_from"] is None and obj["history"][2]["from"] == "/x/last.ckpt"
    assert "signal" not in obj["history"][0] and status.stop == "SIGUSR2 during epoch 3"
    assert [p.name for p in tmp_path.iterdir()] == ["status.json"]  # no temporary file left


def test_a_status_written_by_hand_reads(tmp_path: Path) -> None:
    stop = {"status": "interrupted", "signal": "SIGTERM", "stage": "evaluation"}  # no schema_version: 1
    (tmp_path / "status.json").write_text(json.dumps(stop))
    status = read_status(tmp_path)
    assert status is not None and status.history == () and status.stop == "SIGTERM during the evaluation"
    assert read_status(tmp_path / "nowhere") is None


STATES = "running, completed, failed, interrupted"
NUMBERS = "an object of numbers"


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ('{"status": "running"', "invalid JSON (Expecting ',' delimiter at line 1)"),
        ('["running"]', "expected an object, got list"),
        ('{"status": "done"}', f"status: expected one of {STATES}, got 'done'"),
        ('{"status": "completed", "metrics": {"a": "b"}}', f"metrics: expected {NUMBERS}, got {{'a': 'b'}}"),
        ('{"status": "running", "history": [{"time": "now"}]}', "history[0].event is missing"),
        (
            '{"status": "running", "history": [{"event": "x", "epoch": true}]}',
            "history[0].epoch: expected an integer or null, got True",
        ),
        ('{"schema_version": 2, "status": "running"}', "schema_version 2 is not supported (supported: 1)"),
        (
            '{"schema_version": "1", "status": "running"}',
            "schema_version '1' is not supported (supported: 1)",
        ),
    ],
)
def test_a_malformed_status_is_one_line_naming_the_file(tmp_path: Path, text: str, reason: str) -> None:
    path = tmp_path / "status.json"
    path.write_text(text)
    with pytest.raises(JobFolderError) as caught:
        read_status(tmp_path)
    assert str(caught.value) == f"{path}: {reason}" and "\n" not in str(caught.value)
    (tmp_path / ".hydra").mkdir()
    (tmp_path / ".hydra" / "config.yaml").write_text("selection: {monitor: val/score, mode: min}\n")
    assert load_job(tmp_path).skip == f"status.json: {reason}"  # the report names it too


def test_metrics_read_up_to_a_damaged_row(tmp_path: Path) -> None:
    rows = ["epoch,step,train/loss,val/loss", ",0,,", "0,5,,2.0", "0,5,3.0,", "1,11,,1.5", "1,11,2.5"]
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    table = read_metrics(tmp_path)
    assert table.header == ("epoch", "step", "train/loss", "val/loss") and len(table.rows) == 4
    assert table.damage == "line 6 is truncated or corrupt (3 fields, header has 4): later rows ignored"
    assert table.final() == {"train/loss": 3.0, "val/loss": 1.5}
    assert read_metrics(tmp_path / "nowhere") == MetricsTable()
    (tmp_path / "metrics.csv").write_bytes(b"\xff\xfe")
    with pytest.raises(JobFolderError, match=r"metrics.csv: unreadable \(UnicodeDecodeError\)$"):
        read_metrics(tmp_path)


def _lightning_and_ours(tmp_path: Path, batches: list[list[dict[str, float]]]) -> tuple[bytes, bytes]:
    """The metrics.csv that Lightning's writer and ours write for the same logged rows, saved in batches."""
    files = []
    for name, writer_class in (("lightning", ExperimentWriter), ("ours", AppendingWriter)):
        writer = writer_class(log_dir=str(tmp_path / name))
        for batch in batches:
            for step, metrics in enumerate(batch):
                writer.log_metrics(metrics, step)
            writer.save()
        files.append((tmp_path / name / "metrics.csv").read_bytes())
    return files[0], files[1]


def test_appending_writes_what_lightning_writes(tmp_path: Path) -> None:
    batches = [[{"lr-Adam": 0.001}, {"train/loss": 0.1 / 3, "epoch": 0}],
               [{"val/score": 2.5e-7, "epoch": 0}, {"train/loss": 1e300, "epoch": 1}]]  # fmt: skip
    lightning, ours = _lightning_and_ours(tmp_path, batches)
    assert ours == lightning and lightning.count(b"\n") == 5  # a new column rewrote the header
    again = AppendingWriter(log_dir=str(tmp_path / "ours"))  # a resumed run's logger keeps the file
    again.log_metrics({"train/loss": 0.5, "epoch": 2}, 9)
    again.save()
    assert (tmp_path / "ours" / "metrics.csv").read_bytes().startswith(lightning)


def test_a_resume_replaces_rows_past_the_checkpoint_and_a_cut_row(tmp_path: Path) -> None:
    header = ("epoch", "step", "val/loss")
    rows = ({"epoch": "0", "step": "4", "val/loss": "2.0"}, {"epoch": "1", "step": "9", "val/loss": "1.0"})
    write_metrics(tmp_path, MetricsTable(header, rows))
    append_metrics(tmp_path, header, [])
    with (tmp_path / "metrics.csv").open("a") as f:
        f.write("1,9")  # a process killed while appending
    continue_history(tmp_path, tmp_path, 1, 10)
    assert read_metrics(tmp_path) == MetricsTable(header, rows)  # the cut row gone, the others kept
    continue_history(tmp_path, tmp_path, 0, 5)
    assert read_metrics(tmp_path) == MetricsTable(header, rows[:1])
    other = tmp_path / "other"
    continue_history(other, tmp_path, 0, 5)  # a new folder continuing this one's checkpoint
    assert read_metrics(other) == MetricsTable(header, rows[:1])
