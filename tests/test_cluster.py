"""Sweeps through a real single-node SLURM cluster (``cluster/cluster.sh up``: slurmctld, slurmd, slurmdbd
with MariaDB, munge), started by the fixture. Skipped, with the reason, only where SLURM cannot be installed
(not root, no apt-get); installed but failing to start is a failure."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def cluster() -> None:
    """The cluster up (idempotent: daemons already running are kept)."""
    if os.geteuid() != 0 and shutil.which("sbatch") is None:
        pytest.skip("SLURM is not installed and installing it needs root (cluster/cluster.sh up)")
    if shutil.which("sbatch") is None and shutil.which("apt-get") is None:
        pytest.skip("SLURM is not installed and there is no apt-get to install it")
    up = subprocess.run(["bash", str(ROOT / "cluster" / "cluster.sh"), "up"], capture_output=True, text=True)
    if up.returncode != 0:
        pytest.fail(f"the SLURM cluster did not start: {up.stderr.strip()}")


def sacct_states(job: str) -> dict[str, str]:
    """{job id: state} of a job array's tasks, from the accounting database (what submitit polls)."""
    out = subprocess.run(["sacct", "-j", job, "-X", "-n", "-P", "-o", "JobID,State"], capture_output=True,
                         text=True, check=True).stdout  # fmt: skip
    return dict(line.split("|") for line in out.split())


@pytest.mark.slow
def test_a_two_job_sweep_runs_through_slurm(cluster: None, tiny_kitti: Path, tmp_path: Path) -> None:
    """``hydra/launcher=submitit_slurm_local``: both jobs submitted with sbatch, run under srun, COMPLETED in
    sacct, their folders as a local sweep's; Lightning sees SLURM but leaves the requeue to submitit."""
    sweep = tmp_path / "sweep"
    command = [
        sys.executable, "-m", "lossvo.train", "-m", "hydra/launcher=submitit_slurm_local",
        "loss=euler,chordal",
        "data=kitti", f"data.root={tiny_kitti}", f"data.cache_dir={tmp_path / 'cache'}", "data.train=[00,01]",
        "data.val=[02]", "data.test=[02]", "data.height=64", "data.width=96", "data.seq_len=3",
        "data.num_workers=0", "model.width_mult=0.0625", "model.hidden_size=16", "trainer.max_epochs=1",
        f"hydra.sweep.dir={sweep}",
    ]  # fmt: skip
    run = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and p.name[0].isdigit())
    assert len(jobs) == 2
    array = sorted((sweep / ".submitit").glob("*_0"))[0].name.split("_")[0]
    assert set(sacct_states(array).values()) == {"COMPLETED"} and len(sacct_states(array)) == 2
    for job in jobs:
        assert json.loads((job / "status.json").read_text())["status"] == "completed"
        assert (job / "results.json").is_file() and (job / "checkpoints" / "last.ckpt").is_file()
        log = (job / "train.log").read_text()
        assert "SLURM auto-requeueing enabled" not in log
