"""A real Hydra multirun over three losses, as a subprocess: job folders, checkpoints, metrics, W&B runs,
and a report with baselines and ground truth from the jobs' results.json alone."""

from __future__ import annotations

import csv
import json
import subprocess
from pathlib import Path

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser

from lossvo.report.document import make_report


def run_train(args: list[str], tmp_path: Path, run_tiny_sweep) -> subprocess.CompletedProcess:
    return run_tiny_sweep(tmp_path, tmp_path / "sweep", args)


def test_sweep_over_three_losses_with_wandb(run_tiny_sweep, tmp_path: Path) -> None:
    result = run_train(["loss=euler,quat,chordal", "logger=wandb"], tmp_path, run_tiny_sweep)
    assert result.returncode == 0, result.stderr[-3000:]
    jobs = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    assert [j.name for j in jobs] == [
        "0_experiment-tiny+logger-wandb+loss-euler",
        "1_experiment-tiny+logger-wandb+loss-quat",
        "2_experiment-tiny+logger-wandb+loss-chordal",
    ]
    parser = OverridesParser.create()  # a checkpoint path copied from the sweep is a valid override value
    for job in jobs:
        path = str(job / "checkpoints" / "best.ckpt")
        assert parser.parse_override(f"ckpt_path={path}").value() == path
    for job, loss in zip(jobs, ("euler", "quat", "chordal"), strict=True):
        assert (job / ".hydra" / "config.yaml").is_file()
        assert {p.name for p in (job / "checkpoints").iterdir()} == {"best.ckpt", "last.ckpt"}
        rows = list(csv.DictReader((job / "metrics.csv").open()))
        assert any(r.get("val/rot_err_rad") for r in rows) and any(r.get("train/trans_err_m") for r in rows)
        assert json.loads((job / "status.json").read_text())["status"] == "completed"
        runs = list((job / "wandb").glob("offline-run-*"))
        assert len(runs) == 1, f"{job.name}: expected one W&B run, got {runs}"
        # The run's record (protobuf) holds its config and tag: this job's loss dominates it.
        record = next(runs[0].glob("run-*.wandb")).read_bytes()
        counts = {name: record.count(name.encode()) for name in ("euler", "quat", "chordal")}
        assert max(counts, key=counts.get) == loss, counts
        data = json.loads((job / "results.json").read_text())["data"]
        assert data["train"] == ["00", "01"] and data["root"] == data["train_root"]
    text = make_report(tmp_path / "sweep", n_jobs=1).read_text()
    assert "baselines skipped" not in text and "without ground truth" not in text
    assert "| 02 | " in text.split("## Table I", 1)[1]  # the tiny experiment's test sequence


def test_failing_job_keeps_the_others(run_tiny_sweep, tmp_path: Path) -> None:
    result = run_train(["loss=euler", "optimizer.lr=1e30,1e-3"], tmp_path, run_tiny_sweep)
    assert result.returncode != 0
    assert "non-finite loss at epoch 0" in result.stderr
    failed, finished = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    assert json.loads((failed / "status.json").read_text())["status"] == "failed"
    assert "NonFiniteLossError" in json.loads((failed / "status.json").read_text())["error"]
    assert json.loads((finished / "status.json").read_text())["status"] == "completed"
    assert (finished / "checkpoints" / "best.ckpt").is_file()


@pytest.mark.parametrize("launcher", ["joblib"])
def test_joblib_launcher_runs_jobs_in_parallel_processes(
    run_tiny_sweep, tmp_path: Path, launcher: str
) -> None:
    result = run_train(
        ["loss=euler,quat", f"hydra/launcher={launcher}", "hydra.launcher.n_jobs=2", "data.num_workers=1"],
        tmp_path, run_tiny_sweep,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    jobs = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    assert len(jobs) == 2 and all((j / "checkpoints" / "best.ckpt").is_file() for j in jobs)
    # DataLoader workers start inside joblib's (loky) worker processes too
    assert all(json.loads((j / "status.json").read_text())["status"] == "completed" for j in jobs)


def test_rerunning_a_sweep_skips_completed_jobs_and_resumes_interrupted_ones(
    run_tiny_sweep, tmp_path: Path
) -> None:
    first = run_train(["loss=euler,quat"], tmp_path, run_tiny_sweep)
    assert first.returncode == 0, first.stderr[-3000:]
    done, stopped = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    (done / "results.json").write_text("{}")  # a skipped job leaves its outputs alone
    (stopped / "status.json").write_text(
        json.dumps({"status": "interrupted", "signal": "SIGTERM", "epoch": 1})
    )
    (stopped / "results.json").unlink()
    again = run_tiny_sweep(tmp_path / "again", tmp_path / "sweep", ["loss=euler,quat"])
    assert again.returncode == 0, again.stderr[-3000:]
    log = again.stdout + again.stderr
    assert "already completed (resume=true)" in log and "resuming the interrupted run from" in log
    assert (done / "results.json").read_text() == "{}"
    assert json.loads((stopped / "status.json").read_text())["status"] == "completed"
    assert (stopped / "results.json").is_file()


def test_a_job_with_a_bad_value_fails_alone(run_tiny_sweep, tmp_path: Path) -> None:
    result = run_train(["loss=euler", "optimizer.lr=-1,1e-3"], tmp_path, run_tiny_sweep)
    assert result.returncode != 0
    assert "optimizer.lr: expected" in result.stdout + result.stderr
    bad, good = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    assert not (bad / "status.json").exists()  # refused before anything was built
    assert json.loads((good / "status.json").read_text())["status"] == "completed"
