"""Shared test settings: deterministic hypothesis runs, devices to test on."""

from __future__ import annotations

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
