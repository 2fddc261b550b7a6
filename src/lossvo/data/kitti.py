"""The KITTI odometry format: pose files, calibration, timestamps, image lists, relative targets (sequence
names: :mod:`lossvo.data.sequence`; writing pose files: :mod:`lossvo.data.pose_files`).

Layout (the same for real KITTI and for lossvo's synthetic dataset)::

    ROOT/sequences/NN/image_2/000000.png ...   left colour camera (the one used)
    ROOT/sequences/NN/calib.txt                 P0..P3 (3x4 projections), Tr (3x4)
    ROOT/sequences/NN/times.txt                 one timestamp (s) per frame
    ROOT/poses/NN.txt                           12 floats per frame: the 3x4 [R | t] of T_w_c, row-major

ROOT may also be the folder that holds ``dataset/``. Sequences without a pose file (KITTI 11-21) are
usable for inference only. Every reader fails with one ``KittiFormatError`` naming the file, the line
(1-based) where there is one, and what was expected.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lossvo import geometry
from lossvo.data.sequence import (
    DatasetFormatError,
    Sequence,
    finite_numbers,
    has_ground_truth,
    png_size,
    text_lines,
    where,
)

ORTHONORMAL_TOLERANCE = 1e-3
"""Largest |R^T R - I| entry accepted in a pose file (KITTI stores 7 to 9 significant digits)."""

_PNG_END = b"IEND\xaeB`\x82"


class KittiFormatError(DatasetFormatError):
    """A file or folder that does not follow the KITTI odometry layout."""


# --------------------------------------------------------------------------------------------------
# Root and sequences
# --------------------------------------------------------------------------------------------------


def find_root(root: str | os.PathLike) -> Path:
    """The folder holding ``sequences/``: ``root`` itself or ``root/dataset``.

    Raises:
        KittiFormatError: if neither holds a ``sequences`` folder.
    """
    root = Path(root).expanduser()
    if not root.is_dir():
        raise KittiFormatError(f"{root}: dataset root does not exist (expected a KITTI odometry folder)")
    for candidate in (root, root / "dataset"):
        if (candidate / "sequences").is_dir():
            return candidate
    raise KittiFormatError(
        f"{root}: not a KITTI odometry root: expected {root}/sequences/NN/image_2 and {root}/poses/NN.txt "
        f"(or the same under {root}/dataset)"
    )


def list_sequences(root: Path) -> list[str]:
    """Names of the sequences under ``root/sequences`` (sorted)."""
    return sorted(p.name for p in (root / "sequences").iterdir() if p.is_dir())


def sequence_dir(root: Path, name: str) -> Path:
    """``root/sequences/name``; raises KittiFormatError naming the missing folder and what exists."""
    path = root / "sequences" / name
    if not path.is_dir():
        available = ", ".join(list_sequences(root)) or "none"
        raise KittiFormatError(f"{path}: sequence {name!r} not found (available: {available})")
    return path


def pose_path(root: Path, name: str) -> Path:
    return root / "poses" / f"{name}.txt"


def image_paths(root: Path, name: str, camera: str = "image_2") -> list[Path]:
    """Sorted frame paths of one sequence's camera folder.

    Raises:
        KittiFormatError: if the folder is missing or holds no PNG files.
    """
    folder = sequence_dir(root, name) / camera
    paths = sorted(folder.glob("*.png")) if folder.is_dir() else []
    if not paths:
        raise KittiFormatError(f"{folder}: expected PNG frames 000000.png, 000001.png, ... (found none)")
    return paths


def check_png(path: Path) -> None:
    """Raise KittiFormatError if ``path`` is not a complete PNG file (missing, truncated, not PNG)."""
    try:
        with path.open("rb") as f:
            head = f.read(8)
            f.seek(max(0, path.stat().st_size - 12))
            tail = f.read()
    except OSError as e:
        raise KittiFormatError(f"{path}: unreadable image ({e.strerror})") from None
    if head != b"\x89PNG\r\n\x1a\n" or _PNG_END not in tail:
        raise KittiFormatError(f"{path}: not a complete PNG file (truncated or corrupt)")


# --------------------------------------------------------------------------------------------------
# Pose files
# --------------------------------------------------------------------------------------------------


def _parse_numbers(path: Path, line_no: int, line: str, count: int) -> list[float]:
    fields = line.split()
    if len(fields) != count:
        raise KittiFormatError(f"{where(path, line_no)}: expected {count} numbers, got {len(fields)}")
    return finite_numbers(path, line_no, fields, f"{count} numbers", "finite numbers", KittiFormatError)


def read_poses(path: str | os.PathLike) -> np.ndarray:
    """Read a KITTI pose file.

    Args:
        path: ``poses/NN.txt``, one pose per line: 12 numbers, the row-major 3x4 ``[R | t]`` of T_w_c.
    Returns:
        (N, 4, 4) float64 camera-to-world poses.
    Raises:
        KittiFormatError: naming the file and line for a missing file, a line without 12 numbers, or a
            rotation block far from orthonormal.
    """
    path = Path(path)
    rows = text_lines(path, "pose file", error=KittiFormatError)
    if not rows:
        raise KittiFormatError(f"{path}: empty pose file (expected one line of 12 numbers per frame)")
    first = rows[0][1].split()
    if len(first) == 8 and not rows[0][1].lstrip().startswith("#"):
        raise KittiFormatError(
            f"{where(path, rows[0][0])}: expected 12 numbers (a KITTI pose file), got 8: a TUM trajectory "
            "('timestamp tx ty tz qx qy qz qw')? Name it .tum to read it as one"
        )
    values = np.array([_parse_numbers(path, i, line, 12) for i, line in rows], dtype=np.float64)
    poses = np.zeros((len(values), 4, 4))
    poses[:, :3, :] = values.reshape(-1, 3, 4)
    poses[:, 3, 3] = 1.0
    _check_rotations(path, poses[:, :3, :3], [i for i, _ in rows])
    return poses


def _check_rotations(path: Path, R: np.ndarray, line_numbers: list[int]) -> None:
    error = np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((error > ORTHONORMAL_TOLERANCE) | (det < 0))
    if bad.size:
        k = bad[0]
        raise KittiFormatError(
            f"{where(path, line_numbers[k])}: rotation block is not a rotation "
            f"(max |RᵀR − I| = {error[k]:.2g}, det = {det[k]:.4g}; expected orthonormal, det +1)"
        )


def relative_targets(poses: np.ndarray, step: int = 1) -> np.ndarray:
    """Relative poses between frames ``step`` apart, ``inv(T_w_k) @ T_w_{k+step}``, in float64.

    Args:
        poses: (N, 4, 4) camera-to-world poses; step: frames between the two poses (1: consecutive).
    Returns:
        (N - step, 4, 4) float64 relative poses (frame k+step seen from frame k).
    """
    T_w = torch.from_numpy(np.asarray(poses, np.float64))
    return geometry.relative_pose(T_w[:-step], T_w[step:]).numpy()


# --------------------------------------------------------------------------------------------------
# Calibration and timestamps
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Calib:
    """KITTI calibration: 3x4 projection matrices P0..P3 (P2 = left colour camera), and Tr if given."""

    P: dict[str, np.ndarray]
    Tr: np.ndarray | None

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsics of the left colour camera (image_2), from P2."""
        return self.P["P2"][:, :3].copy()


def read_calib(path: str | os.PathLike) -> Calib:
    """Read ``calib.txt`` (lines ``P0: 12 numbers`` ... ``Tr: 12 numbers``).

    Raises:
        KittiFormatError: naming the file (and line) if it is unreadable, malformed or lacks P2.
    """
    path = Path(path)
    entries: dict[str, np.ndarray] = {}
    for i, line in text_lines(path, "calibration", error=KittiFormatError):
        key, sep, rest = line.partition(":")
        if not sep:
            raise KittiFormatError(f"{where(path, i)}: expected 'KEY: 12 numbers', got {line.strip()!r}")
        entries[key.strip()] = np.array(_parse_numbers(path, i, rest, 12)).reshape(3, 4)
    if "P2" not in entries:
        raise KittiFormatError(f"{path}: no P2 (expected a line 'P2: 12 numbers' for the image_2 camera)")
    return Calib({k: v for k, v in entries.items() if k.startswith("P")}, entries.get("Tr"))


def read_times(path: str | os.PathLike) -> np.ndarray:
    """Read ``times.txt``: (N,) float64 timestamps in seconds, one per line."""
    path = Path(path)
    rows = text_lines(path, "timestamps", error=KittiFormatError)
    return np.array([_parse_numbers(path, i, line, 1)[0] for i, line in rows], dtype=np.float64)


# --------------------------------------------------------------------------------------------------
# A whole sequence
# --------------------------------------------------------------------------------------------------


def load_sequence(root: str | os.PathLike, name: str, require_poses: bool = True) -> Sequence:
    """Read and check one sequence's metadata (frame list, timestamps, poses, calibration) into the data
    contract (:class:`lossvo.data.sequence.Sequence`: K from calib.txt's P2, no distortion, the size from
    the first frame's header); no image is decoded.

    Raises:
        KittiFormatError: missing sequence, pose file (when required), calib or times.txt; a pose or
            timestamp count that is not the frame count.
    """
    root = find_root(root)
    images = image_paths(root, name)
    folder = sequence_dir(root, name)
    calib = read_calib(folder / "calib.txt")
    times = read_times(folder / "times.txt")
    if len(times) != len(images):
        raise KittiFormatError(
            f"{folder / 'times.txt'}: {len(times)} timestamps but {len(images)} frames in {images[0].parent} "
            "(expected one timestamp per frame)"
        )
    path = pose_path(root, name)
    poses = None
    if has_ground_truth(path, name, require_poses, "pose file", KittiFormatError):
        poses = read_poses(path)
        if len(poses) != len(images):
            raise KittiFormatError(
                f"{path}: {len(poses)} poses but {len(images)} frames in {images[0].parent} "
                "(expected one pose per frame)"
            )
    return Sequence(name, images, times, poses, calib.K, np.zeros(5), png_size(images[0]))
