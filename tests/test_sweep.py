"""A real Hydra multirun over three losses, as a subprocess: job folders, checkpoints, metrics, W&B runs."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

TINY = """# @package _global_
defaults:
  - override /data: kitti
data:
  root: {root}
  cache_dir: {cache}
  train: ["00", "01"]
  val: ["02"]
  test: ["02"]
  height: 64
  width: 96
  seq_len: 3
  batch_size: 4
  num_workers: 0
model:
  width_mult: 0.0625
  hidden_size: 16
trainer:
  max_epochs: 1
"""


def run_train(args: list[str], tmp_path: Path, tiny_kitti: Path) -> subprocess.CompletedProcess:
    conf = tmp_path / "conf" / "experiment"
    conf.mkdir(parents=True)
    (conf / "tiny.yaml").write_text(TINY.format(root=tiny_kitti, cache=tmp_path / "cache"))
    env = {**os.environ, "WANDB_SILENT": "true", "WANDB_DISABLE_CODE": "true"}
    command = [sys.executable, "-m", "lossvo.train", "-m", "--config-dir", str(tmp_path / "conf"),
               "experiment=tiny", f"hydra.sweep.dir={tmp_path / 'sweep'}", *args]  # fmt: skip
    return subprocess.run(command, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)


def test_sweep_over_three_losses_with_wandb(tiny_kitti: Path, tmp_path: Path) -> None:
    result = run_train(["loss=euler,quat,chordal", "logger=wandb"], tmp_path, tiny_kitti)
    assert result.returncode == 0, result.stderr[-3000:]
    jobs = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    assert [j.name for j in jobs] == [
        "0_experiment=tiny,logger=wandb,loss=euler",
        "1_experiment=tiny,logger=wandb,loss=quat",
        "2_experiment=tiny,logger=wandb,loss=chordal",
    ]
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


def test_failing_job_keeps_the_others(tiny_kitti: Path, tmp_path: Path) -> None:
    result = run_train(["loss=euler", "optimizer.lr=1e30,1e-3"], tmp_path, tiny_kitti)
    assert result.returncode != 0
    assert "non-finite loss at epoch 0" in result.stderr
    failed, finished = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    assert json.loads((failed / "status.json").read_text())["status"] == "failed"
    assert "NonFiniteLossError" in json.loads((failed / "status.json").read_text())["error"]
    assert json.loads((finished / "status.json").read_text())["status"] == "completed"
    assert (finished / "checkpoints" / "best.ckpt").is_file()


@pytest.mark.parametrize("launcher", ["joblib"])
def test_joblib_launcher_runs_jobs_in_parallel_processes(
    tiny_kitti: Path, tmp_path: Path, launcher: str
) -> None:
    result = run_train(
        ["loss=euler,quat", f"hydra/launcher={launcher}", "hydra.launcher.n_jobs=2"], tmp_path, tiny_kitti
    )
    assert result.returncode == 0, result.stderr[-3000:]
    jobs = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    assert len(jobs) == 2 and all((j / "checkpoints" / "best.ckpt").is_file() for j in jobs)
