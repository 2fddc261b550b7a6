"""Lightning DDP on two CPU processes: one output folder, one metrics.csv, one W&B run; trajectory metrics
pooled across processes equal one process's."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from lossvo.evaluation import metrics
from lossvo.evaluation.trajectories import integrate
from test_train import tiny_overrides

REPO = Path(__file__).resolve().parents[1]


def _epochs(job: Path, key: str = "val/score") -> list[int]:
    with (job / "metrics.csv").open(newline="") as f:
        return [int(float(r["epoch"])) for r in csv.DictReader(f) if r.get(key)]


def test_ddp_on_two_cpu_processes(tiny_kitti: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    args = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), "trainer=ddp", "trainer.accelerator=cpu",
            "trainer.devices=2", "trainer.max_epochs=2", "logger=wandb", f"hydra.run.dir={run}"]  # fmt: skip
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


def _random_trajectory(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    from lossvo import geometry as g

    gen = torch.Generator().manual_seed(seed)
    forward = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    gt_rel = g.make_pose(g.so3_exp(0.05 * torch.randn(n - 1, 3, generator=gen, dtype=torch.float64)),
                         torch.randn(n - 1, 3, generator=gen, dtype=torch.float64) + forward)  # fmt: skip
    noise = g.make_pose(g.so3_exp(0.01 * torch.randn(n - 1, 3, generator=gen, dtype=torch.float64)),
                        0.05 * torch.randn(n - 1, 3, generator=gen, dtype=torch.float64))  # fmt: skip
    return gt_rel, gt_rel @ noise


def _pooled(ranked: list[int]) -> dict:
    ape, rpe, kitti = metrics.APE(), metrics.RPE(delta=2), metrics.KittiOdometryError()
    for seed in ranked:
        gt_rel, est_rel = _random_trajectory(150 + 20 * seed, seed)
        gt = integrate(gt_rel)
        metrics.evaluate_relative(est_rel, gt, "none", 2, pooled=(ape, rpe, kitti))
    return {"ape": ape.compute(), "rpe": rpe.compute(), "kitti": kitti.compute()}


def _flat(tree: dict, prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    for key, value in tree.items():
        out.update(_flat(value, f"{prefix}{key}.") if isinstance(value, dict) else {prefix + key: value})
    return out


def _rank(rank: int, world: int, init: str, out: str) -> None:
    dist.init_process_group("gloo", init_method=init, rank=rank, world_size=world)
    try:
        result = _pooled(list(range(5))[rank::world])  # each process its own sequences
    finally:
        dist.destroy_process_group()
    Path(out, f"{rank}.json").write_text(json.dumps(result))


def test_pooled_trajectory_metrics_across_processes_equal_one_process(tmp_path: Path) -> None:
    """Rank 0 in this process, rank 1 in a spawned one."""
    init = f"file://{tmp_path / 'init'}"
    other = mp.get_context("spawn").Process(target=_rank, args=(1, 2, init, str(tmp_path)))
    other.start()
    try:
        _rank(0, 2, init, str(tmp_path))
    finally:
        other.join(timeout=120)
    assert other.exitcode == 0
    single = _pooled(list(range(5)))
    for rank in (0, 1):
        reduced = json.loads((tmp_path / f"{rank}.json").read_text())
        assert _flat(reduced) == pytest.approx(_flat(single), rel=1e-12), f"rank {rank}"
