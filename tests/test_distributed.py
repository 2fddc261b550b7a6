"""Lightning DDP on two CPU processes: one output folder, one metrics.csv, one W&B run, evaluation on rank
0, and trajectory metrics pooled across the processes equal to one process's."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from lossvo.evaluation import metrics
from lossvo.evaluation.inference import predict_sequence
from lossvo.training.module import VOModule
from test_train import tiny_overrides

pytestmark = pytest.mark.slow  # DDP training in two processes
REPO = Path(__file__).resolve().parents[1]


def _epochs(job: Path, key: str = "val/score") -> list[int]:
    with (job / "metrics.csv").open(newline="") as f:
        return [int(float(r["epoch"])) for r in csv.DictReader(f) if r.get(key)]


def test_ddp_on_two_cpu_processes(tiny_kitti: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    args = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), "data.splits.val=[01,02]", "trainer=ddp",
            "trainer.accelerator=cpu", "trainer.devices=2", "trainer.max_epochs=2", "logger=wandb",
            f"hydra.run.dir={run}"]  # fmt: skip
    env = {
        **os.environ,
        "PYTHONPATH": str(REPO / "src"),
        "WANDB_SILENT": "true",
        "WANDB_DISABLE_CODE": "true",
    }
    proc = subprocess.run([sys.executable, "-m", "lossvo.train", *args], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    assert "sync_batchnorm: off on CPU" in proc.stdout + proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "run"]  # one output folder
    assert [p.relative_to(run) for p in run.rglob("metrics.csv")] == [Path("metrics.csv")]
    assert _epochs(run) == [0, 1] and _epochs(run, "val/rpe_trans_rmse") == [0, 1]
    assert len(list((run / "wandb").glob("offline-run-*"))) == 1  # one W&B run
    assert json.loads((run / "status.json").read_text())["status"] == "completed"
    assert "02" in json.loads((run / "results.json").read_text())["sequences"]  # evaluated on rank 0
    # Each process integrated one of the two validation sequences; the logged metrics pool both.
    with (run / "metrics.csv").open(newline="") as f:
        logged = [r for r in csv.DictReader(f) if r.get("val/rpe_trans_rmse")][-1]
    for key, value in _one_process_metrics(run).items():
        assert float(logged[key]) == pytest.approx(value, rel=1e-6), key  # logged as float32


def _one_process_metrics(run: Path) -> dict[str, float]:
    """What TrajectoryValidation logs for the run's last.ckpt, computed here in one process over all of
    the run's validation sequences."""
    module = VOModule.load_from_checkpoint(run / "checkpoints" / "last.ckpt", map_location="cpu")
    dm = instantiate(OmegaConf.load(run / ".hydra" / "config.yaml").data)
    dm.prepare_data()
    dm.setup("fit")
    ape, rpe, kitti = metrics.APE(), metrics.RPE(delta=1), metrics.KittiOdometryError()
    for name in dm.splits["val"]:
        relative = predict_sequence(module, dm.sequence_inputs(name), dm.prepare, dm.seq_len,
                                    mirror_average=True)  # the training default  # fmt: skip
        gt, est = (torch.as_tensor(a, dtype=torch.float64) for a in (dm.sequence_poses(name), relative))
        metrics.evaluate_relative(est, gt, "none", 1, pooled=(ape, rpe, kitti))
    ape_out, rpe_out = ape.compute(), rpe.compute()
    return {"val/ape_trans_rmse": ape_out["trans"]["rmse"], "val/rpe_trans_rmse": rpe_out["trans"]["rmse"],
            "val/rpe_rot_rmse": rpe_out["rot_rad"]["rmse"]}  # fmt: skip
