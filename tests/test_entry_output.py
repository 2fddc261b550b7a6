"""What a real training command prints on a machine with SLURM's ``srun`` on the PATH, into a pipe:
lossvo's own lines, the run folder once created; no Lightning hint, tip, warning or model summary, no
carriage-return progress; the caches built and the summary in train.log."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra.types import RunMode

from lossvo.data import array_cache
from lossvo.training.loggers import WandbLogger
from lossvo.training.resolvers import sweep_group
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
    assert lossvo_lines[0].endswith("run: preparing the data and the network"), output
    assert any(line.endswith(f"run: {tmp_path / 'run'}") for line in lossvo_lines), output
    assert "Total FLOPs" not in done.stdout and "Warning" not in done.stderr, output  # summary: train.log
    log = (tmp_path / "run" / "train.log").read_text()
    assert "Tip" not in log and "Total params" in log
    assert ": built in " in log  # the frame cache, one line a sequence


def test_a_stale_cache_is_warned_once_and_its_rebuild_logged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = tmp_path / "x.npy"
    fill = lambda out: out.fill(1.0) or {}  # noqa: E731
    array_cache.ensure_array(data, {"v": 1}, (3,), np.float32, fill)
    with caplog.at_level(logging.INFO, logger=array_cache.__name__):
        caplog.clear()
        array_cache.ensure_array(data, {"v": 2}, (3,), np.float32, fill)
    stale = [r for r in caplog.records if "is stale or incomplete" in r.getMessage()]
    built = [r for r in caplog.records if r.getMessage().startswith(f"cache {data}: built in ")]
    assert len(stale) == 1 and len(built) == 1


def test_wandb_is_not_asked_for_anonymous_mode_and_a_single_run_has_no_group(tmp_path: Path) -> None:
    logger = WandbLogger(project="lossvo", save_dir=str(tmp_path), offline=True)
    assert "anonymous" not in logger._wandb_init
    assert sweep_group(RunMode.RUN, "outputs/multirun/x") is None
    assert sweep_group(RunMode.MULTIRUN, "outputs/multirun/x") == "outputs/multirun/x"
