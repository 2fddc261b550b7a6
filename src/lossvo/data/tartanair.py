"""The TartanAir (v1) layout: frame lists, NED poses turned into lossvo's camera convention, the fixed camera.

Layout (``castacks/tartanair_tools``, README "Data directory structure" and ``data_type.md``)::

    ROOT/<env>/<Easy|Hard>/<Pnnn>/image_left/000000_left.png ...   640x480 RGB frames, numbered from 0
    ROOT/<env>/<Easy|Hard>/<Pnnn>/pose_left.txt                     one line a frame: 'tx ty tz qx qy qz qw'

Sequences are named by their path under ROOT: ``"abandonedfactory/Easy/P000"``. A pose line is the left
camera's T_w_c in NED axes (x forward, y right, z down), turned into lossvo's (x right, y down, z forward) by
:func:`ned_to_camera`. The camera is fx = fy = 320, cx = 320, cy = 240 (640x480, no distortion), K scaled to
frames of another size. Times are ``index / rate_hz`` seconds (10 Hz by default). Sources: docs/data.md. Bad
input raises one :class:`~lossvo.data.sequence.DatasetFormatError` line naming the file (and the 1-based line
where there is one) and what was expected.
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
    existing_root,
    finite_numbers,
    has_ground_truth,
    png_size,
    pose_matrices,
    text_lines,
    unit_quaternions,
    where,
)
from lossvo.geometry.camera import resized_intrinsics

IMAGES = "image_left"
POSES = "pose_left.txt"
RATE_HZ = 10.0
"""Default frame rate (Hz): TartanAir V2's documented 10 Hz (v1 documents none)."""

SIZE = (480, 640)
"""(H, W) of TartanAir frames, in pixels: the size :data:`K` belongs to."""

K = np.array([[320.0, 0.0, 320.0], [0.0, 320.0, 240.0], [0.0, 0.0, 1.0]])
"""(3, 3) intrinsics in pixels of the 640x480 frames (``data_type.md``); no distortion."""

QUATERNION_TOLERANCE = 1e-3
"""Largest | ||q|| - 1 | accepted in ``pose_left.txt`` (TartanAir writes about 8 significant digits)."""

NED_TO_CAMERA = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""P, with ``v_cam = P v_ned``: lossvo's x (right) is NED's y, y (down) is NED's z, z (forward) is NED's x.
A cyclic permutation, so a proper rotation (det +1); tartanair_tools' ``ned2cam`` uses the same matrix."""

_FRAME = re.compile(r"([0-9]+)_left\.png")


# --------------------------------------------------------------------------------------------------
# The NED -> camera convention
# --------------------------------------------------------------------------------------------------


def ned_to_camera(T_ned: np.ndarray) -> np.ndarray:
    """Poses whose body and world axes are NED (x forward, y right, z down) in lossvo's convention (x right,
    y down, z forward) for both: ``T = P4 @ T_ned @ P4ᵀ`` with P4 = diag(P, 1), P = :data:`NED_TO_CAMERA`.

    The world changes as ``x_w' = P x_w`` and the body as ``x_b = Pᵀ x_c``, so T_w'c = P T_wb Pᵀ. A step
    forward (+x NED) becomes +z, a step right (+y) +x, a step down (+z) +y; a yaw to the right by theta
    (about NED's +z, down) becomes a rotation by theta about the camera's +y (down).

    Args:
        T_ned: (..., 4, 4) poses.
    Returns:
        (..., 4, 4) float64.
    """
    P4 = np.eye(4)
    P4[:3, :3] = NED_TO_CAMERA
    return P4 @ np.asarray(T_ned, dtype=np.float64) @ P4.T


# --------------------------------------------------------------------------------------------------
# Pose file
# --------------------------------------------------------------------------------------------------


def _parse_line(path: Path, line_no: int, line: str) -> list[float]:
    """The 7 finite numbers of a pose line; DatasetFormatError naming ``path:line_no`` if not."""
    fields = line.split()
    expected = "7 numbers 'tx ty tz qx qy qz qw'"
    if len(fields) != 7:
        raise DatasetFormatError(f"{where(path, line_no)}: expected {expected}, got {len(fields)} fields")
    return finite_numbers(path, line_no, fields, expected, "finite numbers")


def read_poses(path: str | os.PathLike) -> np.ndarray:
    """Read ``pose_left.txt``: one line ``tx ty tz qx qy qz qw`` a frame, NED.

    Returns:
        (N, 4, 4) float64 T_w_c in lossvo's convention (:func:`ned_to_camera`), quaternions normalised.
    Raises:
        DatasetFormatError: naming the file (and line) if it is unreadable or empty, a line has not 7 finite
            numbers, or a quaternion's norm is more than :data:`QUATERNION_TOLERANCE` from 1.
    """
    path = Path(path)
    rows = text_lines(path, "poses")
    if not rows:
        raise DatasetFormatError(
            f"{path}: empty pose file (expected one line 'tx ty tz qx qy qz qw' a frame)"
        )
    values = np.array([_parse_line(path, i, line) for i, line in rows], dtype=np.float64)
    numbers = [i for i, _ in rows]
    q = unit_quaternions(path, numbers, values[:, 3:], "(qx qy qz qw)", QUATERNION_TOLERANCE)
    return ned_to_camera(pose_matrices(values[:, :3], q))


# --------------------------------------------------------------------------------------------------
# Sequences
# --------------------------------------------------------------------------------------------------


def list_sequences(root: str | os.PathLike) -> list[str]:
    """Names ``<env>/<Easy|Hard>/<Pnnn>`` of the folders under ``root`` that hold an ``image_left`` folder
    (sorted).

    Raises:
        DatasetFormatError: if ``root`` is not a folder.
    """
    base = existing_root(root, f"ROOT/<env>/<Easy|Hard>/<Pnnn>/{IMAGES}")
    return sorted(p.parent.relative_to(base).as_posix() for p in base.glob(f"*/*/*/{IMAGES}") if p.is_dir())


def sequence_dir(root: str | os.PathLike, name: str) -> Path:
    """``root/name``; DatasetFormatError naming the missing folder and the sequences found."""
    path = existing_root(root, f"ROOT/<env>/<Easy|Hard>/<Pnnn>/{IMAGES}") / name
    if not (path / IMAGES).is_dir():
        found = ", ".join(list_sequences(root)) or "none"
        raise DatasetFormatError(
            f"{path / IMAGES}: sequence {name!r} not found (expected ROOT/<env>/<Easy|Hard>/<Pnnn>/{IMAGES}; "
            f"found: {found})"
        )
    return path


def image_paths(folder: str | os.PathLike) -> list[Path]:
    """The frames ``000000_left.png``, ``000001_left.png``, ... of an ``image_left`` folder, in order.

    Raises:
        DatasetFormatError: if the folder holds no such frame, or the numbers are not 0, 1, ..., N-1
            (naming the first missing frame).
    """
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
    """Read and check one sequence's metadata (frame list, poses, camera); no frame is decoded.

    Args:
        root: the folder holding the environments; name: ``"<env>/<Easy|Hard>/<Pnnn>"``;
        require_poses: raise when ``pose_left.txt`` is missing (else the sequence has ``poses=None``);
        rate_hz: the frame rate giving the times ``index / rate_hz`` (s).
    Returns:
        Sequence with T_w_c of the left camera in lossvo's convention, :data:`K` (scaled to frames that are
        not 640x480), zero distortion, size (H, W).
    Raises:
        DatasetFormatError: an unknown sequence (naming those found), missing or malformed frames or pose
            file, a pose count that differs from the frame count.
        UserError: if ``rate_hz`` is not positive.
    """
    if not rate_hz > 0:
        raise UserError(f"rate_hz must be positive, got {rate_hz}")
    folder = sequence_dir(root, name)
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
