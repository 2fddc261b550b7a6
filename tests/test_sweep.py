"""Real Hydra multiruns: job folders, checkpoints, metrics and W&B runs of the shared sweep (a subprocess,
joblib launcher), one of its jobs against the same config run alone; failing jobs that keep the others and
re-running a sweep (in process)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import torch
import yaml
from hydra.core.override_parser.overrides_parser import OverridesParser

from conftest import STUDY_LOSSES, STUDY_SEEDS
from helpers import metrics_rows, scores_of, status_of, train_main
from lossvo.training.module import NonFiniteLossError

pytestmark = pytest.mark.slow  # the shared sweep and two sweeps of its own


def test_sweep_over_losses_and_seeds_with_joblib_and_wandb(study_sweep: Path) -> None:
    jobs = sorted(p for p in study_sweep.iterdir() if p.is_dir())
    assert [j.name for j in jobs] == [
        f"{n}_loss-{loss}+seed-{seed}+experiment-tiny"  # the swept keys first
        for n, (loss, seed) in enumerate((loss, seed) for loss in STUDY_LOSSES for seed in STUDY_SEEDS)
    ]
    parser = OverridesParser.create()  # a checkpoint path copied from the sweep is a valid override value
    for job in jobs:
        path = str(job / "checkpoints" / "best.ckpt")
        assert parser.parse_override(f"ckpt_path={path}").value() == path
    for job in jobs:
        overrides = yaml.safe_load((job / ".hydra" / "overrides.yaml").read_text())
        loss = dict(item.split("=", 1) for item in overrides)["loss"]
        assert {p.name for p in (job / "checkpoints").iterdir()} == {"best.ckpt", "last.ckpt"}
        rows = list(csv.DictReader((job / "metrics.csv").open()))
        assert any(r.get("val/rot_err_rad") for r in rows) and any(r.get("train/trans_err_m") for r in rows)
        assert json.loads((job / "status.json").read_text())["status"] == "completed"
        runs = list((job / "wandb").glob("offline-run-*"))
        assert len(runs) == 1, f"{job.name}: expected one W&B run, got {runs}"
        # The run's record (protobuf) holds its config and tag: this job's loss dominates it.
        record = next(runs[0].glob("run-*.wandb")).read_bytes()
        counts = {name: record.count(name.encode()) for name in STUDY_LOSSES}
        assert max(counts, key=counts.get) == loss, counts
        data = json.loads((job / "results.json").read_text())["data"]
        assert data["train"] == ["00", "01"] and data["root"] == data["train_root"]


def test_a_sweep_job_equals_its_config_run_alone_on_its_thread_count(
    study_sweep: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture
) -> None:
    """A job of the shared sweep (a joblib worker, ``threads=null``) records its thread count; the same
    config trained alone in this process with ``threads=`` that count gives every number again."""
    (job,) = study_sweep.glob("*_loss-euler+seed-0+*")
    threads = status_of(job)["threads"]
    assert isinstance(threads, int) and threads >= 1
    conf = study_sweep.parents[1] / "conf"
    alone = tmp_path / "alone"
    args = ["--config-dir", str(conf), "experiment=tiny", "loss=euler", "seed=0", f"threads={threads}",
            "logger=csv", f"hydra.run.dir={alone}"]  # fmt: skip
    found = torch.get_num_threads()
    try:
        assert train_main(args, monkeypatch) == 0
    finally:
        torch.set_num_threads(found)
    ours, theirs = status_of(alone), status_of(job)
    history = [ours.pop("history"), theirs.pop("history")]
    assert metrics_rows(alone) == metrics_rows(job) and ours == theirs
    assert [[e["event"] for e in h] for h in history] == [["started", "completed"]] * 2
    assert scores_of(alone) == scores_of(job) and scores_of(alone)["threads"] == threads
    assert torch.load(alone / "checkpoints" / "best.ckpt", weights_only=True)["threads"] == threads
    capfd.readouterr()
    assert train_main([*args, "trainer.max_epochs=3"], monkeypatch) == 0  # more epochs asked: not extended
    (line,) = [x for x in "".join(capfd.readouterr()).splitlines() if "already completed" in x]
    hint = ("it trained 1 epochs, and trainer.max_epochs=3 does not extend it (its schedule ended there): "
            "train the longer run in another folder (hydra.run.dir=... or hydra.sweep.dir=...)")  # fmt: skip
    assert line.endswith(hint)
    assert status_of(alone)["history"][-1]["event"] == "completed"


def test_failing_jobs_keep_the_others(run_tiny_sweep_here, tmp_path: Path, capfd: pytest.CaptureFixture
                                      ) -> None:  # fmt: skip
    """One job diverges (non-finite loss), one is refused before anything is built (a bad value), the
    third completes. In process, where the sweep's first failure is raised (the command line prints
    its traceback and exits 1)."""
    with pytest.raises(NonFiniteLossError, match="non-finite loss at epoch 0"):  # after every job ran
        run_tiny_sweep_here(tmp_path, tmp_path / "sweep", ["loss=euler", "optimizer.lr=1e30,-1,1e-3"])
    assert "optimizer.lr: expected" in "".join(capfd.readouterr())
    diverged, refused, finished = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    status = json.loads((diverged / "status.json").read_text())
    assert status["status"] == "failed" and "NonFiniteLossError" in status["error"]
    refusal = json.loads((refused / "status.json").read_text())  # refused before anything was built
    assert refusal["status"] == "failed" and "optimizer.lr: expected" in refusal["error"]
    assert json.loads((finished / "status.json").read_text())["status"] == "completed"
    assert (finished / "checkpoints" / "best.ckpt").is_file()


def test_rerunning_a_sweep_skips_completed_jobs_and_resumes_interrupted_ones(
    run_tiny_sweep_here, tmp_path: Path, capfd: pytest.CaptureFixture
) -> None:
    """Both sweeps in process (the shared sweep runs the real command line)."""
    assert run_tiny_sweep_here(tmp_path, tmp_path / "sweep", ["loss=euler,quat"]) == 0
    done, stopped = sorted(p for p in (tmp_path / "sweep").iterdir() if p.is_dir())
    (done / "results.json").write_text("{}")  # a skipped job leaves its outputs alone
    (stopped / "status.json").write_text(
        json.dumps({"status": "interrupted", "signal": "SIGTERM", "epoch": 1})
    )
    (stopped / "results.json").unlink()
    capfd.readouterr()
    assert run_tiny_sweep_here(tmp_path / "again", tmp_path / "sweep", ["loss=euler,quat"]) == 0
    log = "".join(capfd.readouterr())
    assert "already completed (resume=true)" in log and "(resuming from " in log
    assert (done / "results.json").read_text() == "{}"
    assert json.loads((stopped / "status.json").read_text())["status"] == "completed"
    assert (stopped / "results.json").is_file()
