"""The TartanAir (v1) layout (``ROOT/<env>/<Easy|Hard>/<Pnnn>/`` with ``image_left/000000_left.png ...`` and
``pose_left.txt``; docs/data.md): NED poses turned into lossvo's camera axes, the fixed camera, times at
an assumed rate.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from lossvo.console import UserError
from lossvo.data.sequence import (
    DatasetFormatError,
    Sequence,
    find_sequences,
    has_ground_truth,
    number_rows,
    png_size,
    quaternion_poses,
    sequence_folder,
)
from lossvo.geometry.camera import resized_intrinsics

IMAGES = "image_left"
POSES = "pose_left.txt"
SHAPE = "<env>/<Easy|Hard>/<Pnnn>"
RATE_HZ = 10.0
"""Default frame rate (Hz): TartanAir V2's documented 10 Hz (v1 documents none)."""

SIZE = (480, 640)
"""(H, W) of TartanAir frames, in pixels: the size :data:`K` belongs to."""

K = np.array([[320.0, 0.0, 320.0], [0.0, 320.0, 240.0], [0.0, 0.0, 1.0]])
"""(3, 3) intrinsics in pixels of the 640x480 frames (``data_type.md``); no distortion."""

QUATERNION_TOLERANCE = 1e-3
"""Largest | ||q|| - 1 | accepted in ``pose_left.txt`` (TartanAir writes about 8 significant digits)."""

NED_TO_CAMERA = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""P, with ``v_cam = P v_ned``: lossvo's x (right) is NED's y, y (down) is NED's z, z (forward) is NED's x."""

_FRAME = re.compile(r"([0-9]+)_left\.png")


def ned_to_camera(T_ned: np.ndarray) -> np.ndarray:
    """(..., 4, 4) float64 poses whose body and world axes are NED (x forward, y right, z down) in lossvo's
    (x right, y down, z forward) for both: ``P4 @ T_ned @ P4ᵀ``, P4 = diag(:data:`NED_TO_CAMERA`, 1)."""
    P4 = np.eye(4)
    P4[:3, :3] = NED_TO_CAMERA
    return P4 @ np.asarray(T_ned, dtype=np.float64) @ P4.T


def read_poses(path: str | os.PathLike) -> np.ndarray:
    """``pose_left.txt`` (a line ``tx ty tz qx qy qz qw`` a frame, NED): (N, 4, 4) float64 T_w_c in
    lossvo's axes, quaternions normalised."""
    path = Path(path)
    lines, table = number_rows(path, "poses", 7, "7 numbers 'tx ty tz qx qy qz qw'", "finite numbers", False)
    if not lines:
        raise DatasetFormatError(
            f"{path}: empty pose file (expected one line 'tx ty tz qx qy qz qw' a frame)"
        )
    poses = quaternion_poses(path, lines, table[:, :3], table[:, 3:], "(qx qy qz qw)", QUATERNION_TOLERANCE)
    return ned_to_camera(poses)


def list_sequences(root: str | os.PathLike) -> list[str]:
    """Names ``<env>/<Easy|Hard>/<Pnnn>`` of the folders under ``root`` holding ``image_left`` (sorted)."""
    return find_sequences(root, IMAGES, SHAPE)


def image_paths(folder: str | os.PathLike) -> list[Path]:
    """The frames ``000000_left.png``, ``000001_left.png``, ... of an ``image_left`` folder, in order; an
    error if there are none or a number is missing."""
    folder = Path(folder)
    numbered = sorted(
        (int(match.group(1)), p) for p in folder.iterdir() if (match := _FRAME.fullmatch(p.name)) is not None
    )
    if not numbered:
        raise DatasetFormatError(
            f"{folder}: expected frames 000000_left.png, 000001_left.png, ... (found none)"
        )
    numbers = np.array([n for n, _ in numbered])
    gap = np.flatnonzero(numbers != np.arange(len(numbers)))
    if gap.size:
        k = int(gap[0])
        raise DatasetFormatError(
            f"{folder / f'{k:06d}_left.png'}: frame missing (expected frames numbered 0 to "
            f"{len(numbers) - 1} without gaps, found {numbers[k]:06d}_left.png next)"
        )
    return [p for _, p in numbered]


def load_sequence(
    root: str | os.PathLike, name: str, require_poses: bool = True, rate_hz: float = RATE_HZ
) -> Sequence:
    """One sequence's metadata, checked: its frames at times ``index / rate_hz`` s, the left camera's T_w_c
    in lossvo's axes, :data:`K` scaled to frames that are not 640x480. No frame is decoded."""
    if not rate_hz > 0:
        raise UserError(f"rate_hz must be positive, got {rate_hz}")
    folder = sequence_folder(root, name, IMAGES, SHAPE)
    images = image_paths(folder / IMAGES)
    size = png_size(images[0])
    K_seq = resized_intrinsics(K, SIZE, size)
    times = np.arange(len(images), dtype=np.float64) / rate_hz
    path = folder / POSES
    if not has_ground_truth(path, name, require_poses, "pose file"):
        return Sequence(name, images, times, None, K_seq, np.zeros(5), size)
    poses = read_poses(path)
    if len(poses) != len(images):
        raise DatasetFormatError(
            f"{path}: {len(poses)} poses but {len(images)} frames in {folder / IMAGES} "
            "(expected one pose a frame)"
        )
    return Sequence(name, images, times, poses, K_seq, np.zeros(5), size)
