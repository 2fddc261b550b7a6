"""Shared test settings: deterministic hypothesis runs, devices to test on."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, settings

settings.register_profile(
    "lossvo", deadline=None, derandomize=True, max_examples=200, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("lossvo")

DEVICES = [
    "cpu",
    pytest.param(
        "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA is not available")
    ),
]


@pytest.fixture(scope="session")
def tiny_kitti(tmp_path_factory: pytest.TempPathFactory):
    """A tiny synthetic dataset in the KITTI layout (3 sequences of 10 frames, 64x208), shared by tests.

    Tests that modify a dataset copy it first (see ``kitti_copy``).
    """
    from lossvo.data import synthetic

    root = tmp_path_factory.mktemp("tiny_kitti")
    synthetic.generate(root, sequences=("00", "01", "02"), frames=10, height=64, width=208, progress=False)
    return root


@pytest.fixture
def kitti_copy(tiny_kitti, tmp_path):
    """A private, writable copy of ``tiny_kitti``."""
    import shutil

    return shutil.copytree(tiny_kitti, tmp_path / "kitti")


TINY_EXPERIMENT = """# @package _global_
defaults:
  - override /data: kitti
data:
  root: {root}
  cache_dir: {cache}
  train: ["00", "01"]
  val: ["02"]
  test: {test}
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
{trainer_extra}"""
"""Hydra experiment ``experiment=tiny``: the tiny dataset through the KITTI reader, a very small DeepVO."""


@pytest.fixture(scope="session")
def run_tiny_sweep(tiny_kitti: Path) -> Callable[..., subprocess.CompletedProcess]:
    """A function running ``python -m lossvo.train -m experiment=tiny ARGS`` as a subprocess in ``base``
    (config, cache and sweep folders under it), the sweep written to ``sweep_dir``."""

    def run(base: Path, sweep_dir: Path, args: list[str], test: tuple[str, ...] = ("02",),
            trainer_extra: str = "") -> subprocess.CompletedProcess:  # fmt: skip
        conf = base / "conf" / "experiment"
        conf.mkdir(parents=True)
        text = TINY_EXPERIMENT.format(root=tiny_kitti, cache=base / "cache", test=list(test),
                                      trainer_extra=trainer_extra)  # fmt: skip
        (conf / "tiny.yaml").write_text(text)
        env = {**os.environ, "WANDB_SILENT": "true", "WANDB_DISABLE_CODE": "true"}
        command = [sys.executable, "-m", "lossvo.train", "-m", "--config-dir", str(base / "conf"),
                   "experiment=tiny", f"hydra.sweep.dir={sweep_dir}", *args]  # fmt: skip
        return subprocess.run(command, capture_output=True, text=True, env=env, cwd=base, timeout=600)

    return run
