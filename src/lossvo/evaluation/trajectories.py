"""Trajectories: chaining relative poses into absolute ones, and TUM pose files (KITTI's:
:mod:`lossvo.data.kitti`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import roma
import torch
from torch import Tensor

from lossvo import geometry
from lossvo.atomic import write_text_atomic
from lossvo.data.kitti import KittiFormatError
from lossvo.data.sequence import text_lines


def integrate(relative: Tensor, start: Tensor | None = None) -> Tensor:
    """(N, 4, 4) float64 poses ``T_w_0 = start`` (default identity), ``T_w_{k+1} = T_w_k @ T_k`` of
    (N-1, 4, 4) relative ones: a parallel (Hillis-Steele) scan of log2(N) batched products, the rotations
    re-orthonormalised at every level."""
    geometry.check_shape(relative, (4, 4), "relative")
    if relative.dim() != 3:
        raise ValueError(f"relative must have shape (N-1, 4, 4), got {tuple(relative.shape)}")
    first = torch.eye(4, dtype=torch.float64, device=relative.device) if start is None else start.double()
    geometry.check_shape(first, (4, 4), "start")
    prefix = torch.cat((first[None], relative.double()))
    shift = 1
    while shift < len(prefix):  # log2(N) levels, each one batched product over all poses
        combined = prefix[:-shift] @ prefix[shift:]
        prefix = torch.cat((prefix[:shift], _reorthonormalize(combined)))
        shift *= 2
    return prefix


def scale_steps(relative: Tensor, reference: Tensor) -> Tensor:
    """(..., 4, 4) relative poses with each translation scaled to the ``reference`` step's length
    (:func:`lossvo.geometry.scale_to_length`), rotations unchanged."""
    geometry.check_shape(relative, (4, 4), "relative")
    geometry.check_shape(reference, (4, 4), "reference")
    if relative.shape != reference.shape:
        raise ValueError(f"relative {tuple(relative.shape)} and reference {tuple(reference.shape)} differ")
    lengths = torch.linalg.vector_norm(reference[..., :3, 3], dim=-1)
    t = geometry.scale_to_length(relative[..., :3, 3], lengths)
    return geometry.make_pose(relative[..., :3, :3].to(t.dtype), t)


def _reorthonormalize(T: Tensor) -> Tensor:
    return geometry.make_pose(geometry.orthonormalize(T[..., :3, :3]), T[..., :3, 3])


def read_tum(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Times (N,) s and poses (N, 4, 4) float64 of a TUM file (``timestamp tx ty tz qx qy qz qw`` lines);
    KittiFormatError naming the line that is not one."""
    path = Path(path)
    lines = text_lines(path, "TUM file", comments=True, error=KittiFormatError)
    rows = [i for i, _ in lines]
    numbers = [_tum_numbers(path, i, line) for i, line in lines]
    if not rows:
        raise KittiFormatError(f"{path}: no poses (expected lines 'timestamp tx ty tz qx qy qz qw')")
    values = np.array(numbers)
    norms = np.linalg.norm(values[:, 4:], axis=1)
    if (bad := np.flatnonzero(norms < 1e-6)).size:
        raise KittiFormatError(f"{path}:{rows[bad[0]]}: quaternion (qx qy qz qw) has zero norm")
    quat_xyzw = torch.from_numpy(values[:, 4:] / norms[:, None])
    R = roma.unitquat_to_rotmat(quat_xyzw)
    poses = geometry.make_pose(R, torch.from_numpy(values[:, 1:4])).numpy()
    return values[:, 0], poses


def _tum_numbers(path: Path, line_no: int, line: str) -> list[float]:
    fields = line.split()
    try:
        values = [float(v) for v in fields]
    except ValueError:
        values = []
    if len(fields) != 8 or len(values) != 8 or not np.isfinite(values).all():
        raise KittiFormatError(
            f"{path}:{line_no}: expected 8 finite numbers 'timestamp tx ty tz qx qy qz qw', "
            f"got {line.strip()!r}"
        )
    return values


def write_tum(path: str | os.PathLike, times: np.ndarray | Tensor, poses: np.ndarray | Tensor) -> None:
    """Write a TUM trajectory file of times (N,) s and poses (N, 4, 4) atomically."""
    poses_t = torch.as_tensor(np.asarray(poses, dtype=np.float64))
    geometry.check_shape(poses_t, (4, 4), "poses")
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    if poses_t.dim() != 3 or len(times) != len(poses_t):
        raise ValueError(f"times {times.shape} and poses {tuple(poses_t.shape)} must be (N,) and (N, 4, 4)")
    quat_xyzw = roma.rotmat_to_unitquat(geometry.orthonormalize(poses_t[:, :3, :3])).numpy()
    table = np.column_stack((times, poses_t[:, :3, 3].numpy(), quat_xyzw))
    write_text_atomic(Path(path), "\n".join(" ".join(f"{v:.9f}" for v in row) for row in table) + "\n")
