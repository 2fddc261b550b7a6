"""The TUM RGB-D layout (``ROOT/<sequence>/`` with ``rgb.txt``, ``rgb/``, ``groundtruth.txt``; docs/data.md):
frame lists, ground truth, frames paired with ground-truth stamps by time, the Freiburg cameras.
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
    UnknownCameraError,
    check_increasing,
    find_sequences,
    finite_numbers,
    has_ground_truth,
    listed_frames,
    number_rows,
    png_size,
    quaternion_poses,
    sequence_folder,
    text_lines,
    where,
)
from lossvo.geometry.camera import resized_intrinsics

MAX_DIFFERENCE_S = 0.02
"""TUM's ``associate.py`` default: a frame and a ground-truth stamp pair only if less than 0.02 s apart."""

QUATERNION_NORM_TOLERANCE = 1e-2
"""Largest | ||q|| - 1 | accepted in a ground-truth line (TUM writes 4 decimals)."""

SIZE = (480, 640)
"""(H, W) of TUM RGB-D's colour frames, the size :data:`CAMERAS` belong to."""
RGB_LIST = "rgb.txt"
GROUNDTRUTH = "groundtruth.txt"

CAMERAS: dict[str, tuple[tuple[float, float, float, float], tuple[float, float, float, float, float]]] = {
    "freiburg1": (
        (517.306408, 516.469215, 318.643040, 255.313989),
        (0.262383, -0.953104, -0.005358, 0.002628, 1.163314),
    ),
    "freiburg2": (
        (520.908620, 521.007327, 325.141442, 249.701764),
        (0.231222, -0.784899, -0.003257, -0.000105, 0.917205),
    ),
    "freiburg3": ((535.4, 539.2, 320.1, 247.6), (0.0, 0.0, 0.0, 0.0, 0.0)),
}
"""The Freiburg colour cameras: ``(fx, fy, cx, cy)`` in pixels of 640x480 frames and the OpenCV distortion
``(k1, k2, p1, p2, k3)`` (sources: docs/data.md)."""

_CAMERA_IN_NAME = re.compile(r"(?:^|[^a-z0-9])(?:freiburg|fr)([123])(?![0-9])", re.IGNORECASE)


def read_rgb_list(path: str | os.PathLike) -> tuple[np.ndarray, list[str]]:
    """A frame list (``rgb.txt``: '#' comments, then ``timestamp filename`` lines): (N,) float64 seconds,
    strictly increasing, and the N file names relative to the sequence folder."""
    path = Path(path)
    rows = [(i, line.split()) for i, line in text_lines(path, "frame list", comments=True)]
    if not rows:
        raise DatasetFormatError(f"{path}: no frames (expected lines 'timestamp filename')")
    times, names = [], []
    for i, fields in rows:
        if len(fields) != 2:
            raise DatasetFormatError(
                f"{where(path, i)}: expected 2 fields 'timestamp filename', got {len(fields)}"
            )
        times.append(finite_numbers(path, i, fields[:1], "a timestamp in seconds")[0])
        names.append(fields[1])
    stamps = np.array(times, dtype=np.float64)
    check_increasing(path, [i for i, _ in rows], stamps)
    return stamps, names


def read_groundtruth(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """A TUM trajectory (``groundtruth.txt``: '#' comments, then ``timestamp tx ty tz qx qy qz qw`` lines):
    (M,) float64 seconds, strictly increasing, and (M, 4, 4) float64 T_w_c (quaternions normalised)."""
    path = Path(path)
    lines, table = number_rows(path, "ground truth", 8, "8 numbers 'timestamp tx ty tz qx qy qz qw'")
    if not lines:
        raise DatasetFormatError(f"{path}: no poses (expected lines 'timestamp tx ty tz qx qy qz qw')")
    check_increasing(path, lines, table[:, 0])
    poses = quaternion_poses(
        path, lines, table[:, 1:4], table[:, 4:8], "(qx qy qz qw)", QUATERNION_NORM_TOLERANCE
    )
    return table[:, 0], poses


def associate(
    frame_times: np.ndarray, gt_times: np.ndarray, max_difference: float = MAX_DIFFERENCE_S
) -> tuple[np.ndarray, np.ndarray]:
    """Frames paired with ground-truth stamps as TUM's ``associate.py`` pairs them (no interpolation): of
    the pairs less than ``max_difference`` s apart, greedily the closest first (ties by frame, then by
    stamp), each frame and stamp used once.

    Args:
        frame_times: (N,) seconds, increasing; gt_times: (M,) seconds, strictly increasing.
    Returns:
        (K,) int64 frame indices, increasing, and the (K,) int64 ground-truth index paired with each.
    """
    frame_times = np.asarray(frame_times, dtype=np.float64)
    gt_times = np.asarray(gt_times, dtype=np.float64)
    if np.any(np.diff(gt_times) <= 0):
        raise UserError("gt_times must be strictly increasing")
    frames, stamps = _candidates(frame_times, gt_times, max_difference)
    order = np.lexsort((stamps, frames, np.abs(frame_times[frames] - gt_times[stamps])))
    frames, stamps = frames[order], stamps[order]
    chosen_frames, chosen_stamps = [], []
    while frames.size:  # rounds of pairs first for both their frame and their stamp: the greedy takes them
        first_of_frame = np.zeros(frames.size, bool)
        first_of_frame[np.unique(frames, return_index=True)[1]] = True
        first_of_stamp = np.zeros(stamps.size, bool)
        first_of_stamp[np.unique(stamps, return_index=True)[1]] = True
        take = first_of_frame & first_of_stamp
        chosen_frames.append(frames[take])
        chosen_stamps.append(stamps[take])
        keep = ~np.isin(frames, frames[take]) & ~np.isin(stamps, stamps[take])
        frames, stamps = frames[keep], stamps[keep]
    frame_index = np.concatenate([np.zeros(0, np.int64), *chosen_frames])
    gt_index = np.concatenate([np.zeros(0, np.int64), *chosen_stamps])
    by_frame = np.argsort(frame_index, kind="stable")
    return frame_index[by_frame], gt_index[by_frame]


def _candidates(
    frame_times: np.ndarray, gt_times: np.ndarray, max_difference: float
) -> tuple[np.ndarray, np.ndarray]:
    """(P,) int64 frame and ground-truth indices of every pair less than ``max_difference`` apart: by
    ``searchsorted`` with a stamp of margin each side, then the exact test."""
    lo = np.maximum(np.searchsorted(gt_times, frame_times - max_difference, side="left") - 1, 0)
    hi = np.minimum(np.searchsorted(gt_times, frame_times + max_difference, side="right") + 1, len(gt_times))
    counts = np.maximum(hi - lo, 0)
    frames = np.repeat(np.arange(len(frame_times)), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    stamps = np.repeat(lo, counts) + offsets
    close = np.abs(frame_times[frames] - gt_times[stamps]) < max_difference
    return frames[close].astype(np.int64), stamps[close].astype(np.int64)


def camera(
    name: str,
    K: np.ndarray | None = None,
    distortion: np.ndarray | None = None,
    size: tuple[int, int] = SIZE,
) -> tuple[np.ndarray, np.ndarray]:
    """(3, 3) K and (D,) distortion of a sequence's camera: those of the Freiburg set-up its name names
    (``freiburg1``, ``fr1``: :data:`CAMERAS`), K scaled to frames of ``size`` (H, W), each replaced by the
    caller's where given. A name that names none needs ``K``; its distortion defaults to zeros."""
    match = _CAMERA_IN_NAME.search(name)
    key = f"freiburg{match.group(1)}" if match else None
    if key is None and K is None:
        raise UnknownCameraError(
            f"sequence {name!r}: unknown camera (the name contains none of freiburg1/2/3, fr1/2/3); "
            "give its K (3x3 intrinsics in pixels) and distortion (k1 k2 p1 p2 k3)"
        )
    if K is None:
        fx, fy, cx, cy = CAMERAS[str(key)][0]
        K = resized_intrinsics(np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), SIZE, size)
    if distortion is None:
        distortion = np.array(CAMERAS[key][1]) if key else np.zeros(5)
    K_out, d_out = np.asarray(K, dtype=np.float64), np.asarray(distortion, dtype=np.float64)
    if K_out.shape != (3, 3):
        raise UserError(f"sequence {name!r}: K of shape {K_out.shape}, expected (3, 3)")
    if d_out.shape not in ((4,), (5,), (8,), (12,), (14,)):
        raise UserError(f"sequence {name!r}: distortion of shape {d_out.shape}, expected (4,), (5,), ...")
    return K_out, d_out


def list_sequences(root: str | os.PathLike) -> list[str]:
    """Names of the folders under ``root`` holding an ``rgb.txt`` (sorted)."""
    return find_sequences(root, RGB_LIST, "<sequence>")


def load_sequence(
    root: str | os.PathLike,
    name: str,
    require_poses: bool = True,
    K: np.ndarray | None = None,
    distortion: np.ndarray | None = None,
    max_difference: float = MAX_DIFFERENCE_S,
) -> Sequence:
    """One sequence's metadata, checked; no frame is decoded. Frames without a ground-truth stamp
    (:func:`associate`) are left out and counted in ``dropped``; without a ground-truth file and
    ``require_poses`` every frame is kept and ``poses`` is None. ``K``, ``distortion``: see :func:`camera`.
    """
    folder = sequence_folder(root, name, RGB_LIST, "<sequence>")
    rgb_path = folder / RGB_LIST
    times, names = read_rgb_list(rgb_path)
    images = listed_frames(rgb_path, folder, names)
    size = png_size(images[0])
    K_seq, d_seq = camera(name, K, distortion, size)
    gt_path = folder / GROUNDTRUTH
    if not has_ground_truth(gt_path, name, require_poses):
        return Sequence(name, images, times, None, K_seq, d_seq, size)
    gt_times, gt_poses = read_groundtruth(gt_path)
    frame_index, gt_index = associate(times, gt_times, max_difference)
    if frame_index.size == 0:
        raise DatasetFormatError(
            f"{gt_path}: no frame of {rgb_path} within {max_difference} s of a ground-truth stamp (frames "
            f"{times[0]:.3f}..{times[-1]:.3f} s, ground truth {gt_times[0]:.3f}..{gt_times[-1]:.3f} s)"
        )
    images = [images[k] for k in frame_index]
    dropped = len(times) - frame_index.size
    return Sequence(name, images, times[frame_index], gt_poses[gt_index], K_seq, d_seq, size, dropped=dropped)
