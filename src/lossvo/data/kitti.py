"""The KITTI odometry layout (``ROOT/sequences/NN/`` with ``image_2/``, ``calib.txt``, ``times.txt``, and
``ROOT/poses/NN.txt``; docs/data.md): pose files, calibration, timestamps, frames, relative targets.
Pose files are written by :mod:`lossvo.data.pose_files`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from lossvo import geometry
from lossvo.data.sequence import (
    DatasetFormatError,
    Sequence,
    check_rotations,
    finite_numbers,
    has_ground_truth,
    png_size,
    text_lines,
    where,
)

ORTHONORMAL_TOLERANCE = 1e-3
"""Largest |RᵀR − I| entry accepted in a pose file (KITTI stores 7 to 9 significant digits)."""


class KittiFormatError(DatasetFormatError):
    """A file or folder that does not follow the KITTI odometry layout."""


def find_root(root: str | os.PathLike) -> Path:
    """The folder holding ``sequences/``: ``root`` itself or ``root/dataset``."""
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
    """``root/sequences/name``; an error naming it and the sequences there when it is missing."""
    path = root / "sequences" / name
    if not path.is_dir():
        available = ", ".join(list_sequences(root)) or "none"
        raise KittiFormatError(f"{path}: sequence {name!r} not found (available: {available})")
    return path


def pose_path(root: Path, name: str) -> Path:
    """``root/poses/<name>.txt``."""
    return root / "poses" / f"{name}.txt"


def image_paths(root: Path, name: str, camera: str = "image_2") -> list[Path]:
    """The sorted PNG frames of one sequence's camera folder (an error if there are none)."""
    folder = sequence_dir(root, name) / camera
    paths = sorted(folder.glob("*.png")) if folder.is_dir() else []
    if not paths:
        raise KittiFormatError(f"{folder}: expected PNG frames 000000.png, 000001.png, ... (found none)")
    return paths


def check_png(path: Path) -> None:
    """An error unless ``path`` is a complete PNG file (missing, truncated, not PNG)."""
    try:
        with path.open("rb") as f:
            head = f.read(8)
            f.seek(max(0, path.stat().st_size - 12))
            tail = f.read()
    except OSError as e:
        raise KittiFormatError(f"{path}: unreadable image ({e.strerror})") from None
    if head != b"\x89PNG\r\n\x1a\n" or b"IEND\xaeB`\x82" not in tail:
        raise KittiFormatError(f"{path}: not a complete PNG file (truncated or corrupt)")


def _parse_numbers(path: Path, line_no: int, line: str, count: int) -> list[float]:
    fields = line.split()
    if len(fields) != count:
        raise KittiFormatError(f"{where(path, line_no)}: expected {count} numbers, got {len(fields)}")
    return finite_numbers(path, line_no, fields, f"{count} numbers", "finite numbers", KittiFormatError)


def read_poses(path: str | os.PathLike) -> np.ndarray:
    """(N, 4, 4) float64 T_w_c of a KITTI pose file (a line: the row-major 3x4 ``[R | t]``)."""
    path = Path(path)
    rows = text_lines(path, "pose file", error=KittiFormatError)
    if not rows:
        raise KittiFormatError(f"{path}: empty pose file (expected one line of 12 numbers per frame)")
    if len(rows[0][1].split()) == 8 and not rows[0][1].lstrip().startswith("#"):
        raise KittiFormatError(
            f"{where(path, rows[0][0])}: expected 12 numbers (a KITTI pose file), got 8: a TUM trajectory "
            "('timestamp tx ty tz qx qy qz qw')? Name it .tum to read it as one"
        )
    values = np.array([_parse_numbers(path, i, line, 12) for i, line in rows], dtype=np.float64)
    poses = np.tile(np.eye(4), (len(values), 1, 1))
    poses[:, :3, :] = values.reshape(-1, 3, 4)
    places = [where(path, i) for i, _ in rows]
    check_rotations(places, poses[:, :3, :3], ORTHONORMAL_TOLERANCE, KittiFormatError)
    return poses


def relative_targets(poses: np.ndarray, step: int = 1) -> np.ndarray:
    """(N - step, 4, 4) float64 relative poses ``inv(T_w_k) @ T_w_{k+step}`` of (N, 4, 4) poses."""
    T_w = torch.from_numpy(np.asarray(poses, np.float64))
    return geometry.relative_pose(T_w[:-step], T_w[step:]).numpy()


def read_calib(path: str | os.PathLike) -> np.ndarray:
    """(3, 3) intrinsics of the left colour camera (image_2): P2 of ``calib.txt`` (``KEY: 12 numbers``)."""
    path = Path(path)
    entries: dict[str, np.ndarray] = {}
    for i, line in text_lines(path, "calibration", error=KittiFormatError):
        key, sep, rest = line.partition(":")
        if not sep:
            raise KittiFormatError(f"{where(path, i)}: expected 'KEY: 12 numbers', got {line.strip()!r}")
        entries[key.strip()] = np.array(_parse_numbers(path, i, rest, 12)).reshape(3, 4)
    if "P2" not in entries:
        raise KittiFormatError(f"{path}: no P2 (expected a line 'P2: 12 numbers' for the image_2 camera)")
    return entries["P2"][:, :3].copy()


def read_times(path: str | os.PathLike) -> np.ndarray:
    """(N,) float64 seconds of ``times.txt``, one a line."""
    path = Path(path)
    rows = text_lines(path, "timestamps", error=KittiFormatError)
    return np.array([_parse_numbers(path, i, line, 1)[0] for i, line in rows], dtype=np.float64)


def load_sequence(root: str | os.PathLike, name: str, require_poses: bool = True) -> Sequence:
    """One sequence's metadata, checked (K from calib.txt's P2, no distortion, the size from the first
    frame's header); no frame is decoded."""
    root = find_root(root)
    images = image_paths(root, name)
    folder = sequence_dir(root, name)
    K = read_calib(folder / "calib.txt")
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
    return Sequence(name, images, times, poses, K, np.zeros(5), png_size(images[0]))
