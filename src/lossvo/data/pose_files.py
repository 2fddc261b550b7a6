"""Poses written as a KITTI pose file: 12 numbers a line, the row-major 3x4 ``[R | t]`` of T_w_c (the
trajectory format lossvo writes and evo reads; :func:`lossvo.data.kitti.read_poses` reads it)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from lossvo.atomic import write_text_atomic


def write_poses(path: str | os.PathLike, poses: np.ndarray | torch.Tensor) -> None:
    """Write (N, 4, 4) or (N, 3, 4) poses as a KITTI pose file, atomically, with 17 significant digits (a
    float64 reads back exactly)."""
    poses = np.asarray(poses.detach().cpu() if isinstance(poses, torch.Tensor) else poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] not in ((4, 4), (3, 4)):
        raise ValueError(f"poses must have shape (N, 4, 4) or (N, 3, 4), got {poses.shape}")
    rows = poses[:, :3, :].reshape(-1, 12)
    write_text_atomic(Path(path), "".join(" ".join(f"{v:.16e}" for v in row) + "\n" for row in rows))
