"""What a real training command prints on a machine with SLURM's ``srun`` on the PATH, into a pipe:
lossvo's own lines, the run folder first; no Lightning hint or tip, no carriage-return progress."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from test_train import tiny_overrides


@pytest.mark.slow
def test_a_piped_training_run_prints_no_lightning_hints_and_no_progress_redraws(
    tiny_kitti: Path, tmp_path: Path
) -> None:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    srun = bin_dir / "srun"
    srun.write_text("#!/bin/sh\nexit 0\n")
    srun.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "LOSSVO_CACHE": str(tmp_path)}
    for name in ("SLURM_JOB_ID", "SLURM_NTASKS", "SLURM_JOB_NAME", "LOSSVO_FULL_ERROR"):
        env.pop(name, None)
    args = [f"hydra.run.dir={tmp_path / 'run'}", *tiny_overrides(tiny_kitti, tmp_path / "cache"),
            "trainer.max_epochs=1", "+evaluate=false", "+trainer.limit_train_batches=1",
            "+trainer.limit_val_batches=1", "callbacks.trajectory_validation=null"]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "lossvo.train", *args], capture_output=True, text=True,
                          env=env, timeout=600)  # fmt: skip
    output = done.stdout + done.stderr
    assert done.returncode == 0, output
    assert "srun" not in output and "Tip" not in output and "litmodels" not in output, output
    assert "\r" not in output, output
    lossvo_lines = [line for line in done.stdout.splitlines() if "[lossvo]" in line]
    assert "run folder" in lossvo_lines[0] and str(tmp_path / "run") in lossvo_lines[0], output
