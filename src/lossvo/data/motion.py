"""Per-frame motion statistics of a dataset's ground truth, by split: how fast and how sharply it moves.

Speed is the norm of ``inv(T_w_k) @ T_w_{k+1}``'s translation (m/frame), rotation its angle (rad/frame); a
split's row pools its sequences' pairs. The table: ``python -m lossvo.motion`` (docs/data.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from lossvo import geometry
from lossvo.data import kitti, layouts

STANDING = 0.01
"""Metres per frame below which a pair counts as standing still."""
_SPEED = ("mean", "RMS", "p5", "p50", "p95", "max")
_ROTATION = ("mean", "RMS", "p50", "p95", "max")
POSES_ONLY = (np.eye(3), np.zeros(5))
"""The camera given to every reader here: the table reads poses only, and a TUM sequence whose name names no
Freiburg set-up then needs no camera of its own."""
COLUMNS = ("pairs", *(f"speed {c}" for c in _SPEED), "standing", *(f"rot {c}" for c in _ROTATION))
"""Table columns: speeds in m/frame, rotations in rad/frame, standing as a fraction of the pairs."""


def frame_motion(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed (N-1,) m/frame and rotation angle (N-1,) rad/frame between consecutive poses (N, 4, 4)."""
    rel = kitti.relative_targets(np.asarray(poses, dtype=np.float64))
    angle = geometry.rotation_angle(torch.from_numpy(rel[:, :3, :3])).numpy()
    return np.linalg.norm(rel[:, :3, 3], axis=1), angle


def _spread(x: np.ndarray, percentiles: list[int]) -> list[float]:
    return [x.mean(), np.sqrt((x**2).mean()), *np.percentile(x, percentiles), x.max()]


def statistics(speed: np.ndarray, rotation: np.ndarray) -> dict[str, float]:
    """The :data:`COLUMNS` of pooled pairs: speed (P,) m/frame, rotation (P,) rad/frame."""
    values = [
        len(speed),
        *_spread(speed, [5, 50, 95]),
        (speed < STANDING).mean(),
        *_spread(rotation, [50, 95]),
    ]
    return dict(zip(COLUMNS, map(float, values), strict=True))


def split_statistics(
    motion: Mapping[str, tuple[np.ndarray, np.ndarray]], splits: Mapping[str, Sequence[str]]
) -> dict[str, dict[str, float]]:
    """Rows {label: statistics}: one per non-empty split (its sequences' pairs pooled), then one per sequence.

    motion: {sequence: (speed, rotation)} as :func:`frame_motion` returns them.
    """
    rows = {}
    for split, names in splits.items():
        present = [n for n in names if n in motion]
        if present:
            speed = np.concatenate([motion[n][0] for n in present])
            rotation = np.concatenate([motion[n][1] for n in present])
            rows[f"{split} ({', '.join(present)})"] = statistics(speed, rotation)
    for name in sorted(motion):
        rows[name] = statistics(*motion[name])
    return rows


def read_motion(root: Path, names: Sequence[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{sequence: (speed, rotation)} of the sequences under root that have a poses file."""
    paths = {name: kitti.pose_path(root, name) for name in names}
    return {name: frame_motion(kitti.read_poses(path)) for name, path in paths.items() if path.is_file()}


def read_layout_motion(
    layout: str, root: Path, names: Sequence[str]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{sequence: (speed, rotation)} of sequences read by the ``layout``'s reader
    (:mod:`lossvo.data.layouts`): every one found under ``root`` when ``names`` is empty."""
    chosen = list(names) or layouts.list_sequences(layout, root)
    poses = {name: layouts.load_sequence(layout, root, name, camera=POSES_ONLY).poses for name in chosen}
    return {name: frame_motion(p) for name, p in poses.items() if p is not None}
