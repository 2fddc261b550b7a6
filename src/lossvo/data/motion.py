"""Per-frame motion statistics of a dataset's ground truth, by split: how fast and how sharply it moves.

For each consecutive pair the relative pose ``inv(T_w_k) @ T_w_{k+1}`` gives a speed (its translation's
norm, m/frame) and a rotation (its angle, rad/frame). A split's row pools its sequences' pairs: mean, RMS,
5th/50th/95th percentiles and maximum of each, and the fraction of pairs standing still (< 1 cm).

Their table, one row per split, then one per sequence: ``python -m lossvo.motion`` (:mod:`lossvo.motion`).
Per frame, so datasets recorded at different rates differ by that too (docs/data.md).
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
COLUMNS = (
    "pairs",
    "speed mean",
    "speed RMS",
    "speed p5",
    "speed p50",
    "speed p95",
    "speed max",
    "standing",
    "rot mean",
    "rot RMS",
    "rot p50",
    "rot p95",
    "rot max",
)
"""Table columns: speeds in m/frame, rotations in rad/frame, standing as a fraction of the pairs."""


def frame_motion(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed (N-1,) m/frame and rotation angle (N-1,) rad/frame between consecutive poses (N, 4, 4).

    The angle is :func:`lossvo.geometry.rotation_angle` of the relative rotation (accurate at small and
    large angles).
    """
    rel = kitti.relative_targets(np.asarray(poses, dtype=np.float64))
    angle = geometry.rotation_angle(torch.from_numpy(rel[:, :3, :3])).numpy()
    return np.linalg.norm(rel[:, :3, 3], axis=1), angle


def statistics(speed: np.ndarray, rotation: np.ndarray) -> dict[str, float]:
    """The :data:`COLUMNS` of pooled pairs: speed (P,) m/frame, rotation (P,) rad/frame."""
    p5, p50, p95 = np.percentile(speed, [5, 50, 95])
    r50, r95 = np.percentile(rotation, [50, 95])
    values = (
        len(speed),
        speed.mean(),
        np.sqrt((speed**2).mean()),
        p5,
        p50,
        p95,
        speed.max(),
        (speed < STANDING).mean(),
        rotation.mean(),
        np.sqrt((rotation**2).mean()),
        r50,
        r95,
        rotation.max(),
    )
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
    motion = {}
    for name in names:
        path = kitti.pose_path(root, name)
        if path.is_file():
            motion[name] = frame_motion(kitti.read_poses(path))
    return motion


def read_layout_motion(
    layout: str, root: Path, names: Sequence[str]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{sequence: (speed, rotation)} of sequences read by the ``layout``'s reader
    (:mod:`lossvo.data.layouts`): every one found under ``root`` when ``names`` is empty."""
    chosen = list(names) or layouts.list_sequences(layout, root)
    poses = {name: layouts.load_sequence(layout, root, name).poses for name in chosen}
    return {name: frame_motion(p) for name, p in poses.items() if p is not None}
