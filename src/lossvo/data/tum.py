"""The TUM RGB-D layout: frame lists, ground truth, association by time, the Freiburg cameras.

Layout (TUM's own, https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats)::

    ROOT/<sequence>/rgb.txt          '# comments', then lines 'timestamp filename' (relative to the sequence)
    ROOT/<sequence>/rgb/*.png        640x480 colour frames
    ROOT/<sequence>/groundtruth.txt  '# comments', then lines 'timestamp tx ty tz qx qy qz qw' (~100 Hz)

Sequences keep TUM's names (``rgbd_dataset_freiburg1_xyz``). A ground-truth row is the colour camera's T_w_c
in the mocap world, its axes already lossvo's (x right, y down, z forward). Frames are paired with
ground-truth stamps by time (:func:`associate`, TUM's ``associate.py``); frames without a close stamp are
dropped and counted in ``Sequence.dropped``. Bad input raises one ``DatasetFormatError`` naming the file, the
line (1-based) where there is one, and what was expected.
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
    listed_frames,
    png_size,
    pose_matrices,
    text_lines,
    unit_quaternions,
    where,
)
from lossvo.geometry.camera import resized_intrinsics

MAX_DIFFERENCE_S = 0.02
"""TUM's ``associate.py`` default: a frame and a ground-truth stamp pair only if less than 0.02 s apart."""

QUATERNION_NORM_TOLERANCE = 1e-2
"""Largest | ||q|| - 1 | accepted in a ground-truth line (TUM writes 4 decimals: ||q|| is 1 within ~1e-4)."""

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
"""The colour cameras of the three Freiburg set-ups: ``(fx, fy, cx, cy)`` in pixels of the 640x480 frames and
the OpenCV distortion ``(k1, k2, p1, p2, k3)``. TUM's calibration table (file_formats page, 4 digits there:
fr1 517.3 516.5 318.6 255.3, d 0.2624 -0.9531 -0.0054 0.0026 1.1633; fr2 520.9 521.0 325.1 249.7, d 0.2312
-0.7849 -0.0033 -0.0001 0.9172; fr3 535.4 539.2 320.1 247.6, d 0, its frames already undistorted); the full
digits as ORB-SLAM2 ships them (``Examples/Monocular/TUM1.yaml``, ``TUM2.yaml``, ``TUM3.yaml``)."""

_CAMERA_IN_NAME = re.compile(r"(?:^|[^a-z0-9])(?:freiburg|fr)([123])(?![0-9])", re.IGNORECASE)


# --------------------------------------------------------------------------------------------------
# Text files
# --------------------------------------------------------------------------------------------------


def _data_lines(path: Path, what: str) -> list[tuple[int, list[str]]]:
    """The fields of every line of ``path`` that is neither empty nor a '#' comment, with its 1-based number
    (:func:`lossvo.data.sequence.text_lines`)."""
    return [(i, line.split()) for i, line in text_lines(path, what, comments=True)]


def _check_increasing(path: Path, times: np.ndarray, line_numbers: list[int]) -> None:
    """Raise ``DatasetFormatError`` at the first line whose timestamp is not after the previous line's.

    Args:
        times: (N,) seconds; line_numbers: the N lines they were read from.
    """
    bad = np.flatnonzero(np.diff(times) <= 0)
    if bad.size:
        k = bad[0] + 1
        raise DatasetFormatError(
            f"{where(path, line_numbers[k])}: timestamp {times[k]!r} is not after the previous line's "
            f"{times[k - 1]!r} (expected strictly increasing timestamps)"
        )


def read_rgb_list(path: str | os.PathLike) -> tuple[np.ndarray, list[str]]:
    """Read a TUM frame list (``rgb.txt``): '#' comments, then lines ``timestamp filename``.

    Returns:
        (N,) float64 timestamps in seconds, strictly increasing, and the N filenames relative to the sequence
        folder, in the file's order.
    Raises:
        DatasetFormatError: naming the file (and line) if it is unreadable or empty, a line has not two
            fields, a timestamp is not a finite number, or the timestamps do not strictly increase.
    """
    path = Path(path)
    rows = _data_lines(path, "frame list")
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
    _check_increasing(path, stamps, [i for i, _ in rows])
    return stamps, names


def read_groundtruth(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory (``groundtruth.txt``): '#' comments, then ``timestamp tx ty tz qx qy qz qw``
    lines (the colour camera's optical centre in metres and its orientation, both in the world).

    Returns:
        (M,) float64 timestamps in seconds, strictly increasing, and (M, 4, 4) float64 poses T_w_c: the
        rotation of the normalised quaternion (x, y, z, w), the translation (tx, ty, tz) in metres.
    Raises:
        DatasetFormatError: naming the file (and line) if it is unreadable or empty, a line has not 8 numbers,
            a timestamp does not strictly increase, or a quaternion's norm is far from 1.
    """
    path = Path(path)
    rows = _data_lines(path, "ground truth")
    if not rows:
        raise DatasetFormatError(f"{path}: no poses (expected lines 'timestamp tx ty tz qx qy qz qw')")
    expected = "8 numbers 'timestamp tx ty tz qx qy qz qw'"
    values = []
    for i, fields in rows:
        if len(fields) != 8:
            raise DatasetFormatError(f"{where(path, i)}: expected {expected}, got {len(fields)} fields")
        values.append(finite_numbers(path, i, fields, expected))
    table = np.array(values, dtype=np.float64)
    line_numbers = [i for i, _ in rows]
    _check_increasing(path, table[:, 0], line_numbers)
    quaternions = unit_quaternions(
        path, line_numbers, table[:, 4:8], "(qx qy qz qw)", QUATERNION_NORM_TOLERANCE
    )
    return table[:, 0], pose_matrices(table[:, 1:4], quaternions)


# --------------------------------------------------------------------------------------------------
# Association by time
# --------------------------------------------------------------------------------------------------


def associate(
    frame_times: np.ndarray, gt_times: np.ndarray, max_difference: float = MAX_DIFFERENCE_S
) -> tuple[np.ndarray, np.ndarray]:
    """Pair frames with ground-truth stamps as TUM's ``associate.py`` does: nearest-neighbour association, not
    interpolation (a frame takes the pose of one ground-truth row, never a pose between two).

    The candidates are all pairs (i, j) with ``|frame_times[i] - gt_times[j]| < max_difference``; they are
    taken greedily by smallest difference (ties by frame, then by stamp, as ``associate.py``'s tuple sort),
    each frame and each stamp used at most once. The result is the unique greedy matching, computed as rounds
    of locally dominant pairs (a pair that comes first for both its frame and its stamp is one the greedy
    takes): each round is vectorised, and rounds are few because only chains of pairs competing for a
    frame or a stamp need more than one.

    Args:
        frame_times: (N,) seconds, increasing; gt_times: (M,) seconds, strictly increasing;
        max_difference: seconds (strict bound).
    Returns:
        (K,) int64 frame indices, increasing, and the (K,) int64 ground-truth index paired with each.
    """
    frame_times = np.asarray(frame_times, dtype=np.float64)
    gt_times = np.asarray(gt_times, dtype=np.float64)
    if np.any(np.diff(gt_times) <= 0):
        raise UserError("gt_times must be strictly increasing")
    frames, stamps = _candidates(frame_times, gt_times, max_difference)
    difference = np.abs(frame_times[frames] - gt_times[stamps])
    order = np.lexsort((stamps, frames, difference))
    frames, stamps = frames[order], stamps[order]
    chosen_frames, chosen_stamps = [], []
    while frames.size:
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
    """Every pair (i, j) with ``|frame_times[i] - gt_times[j]| < max_difference``, found by ``searchsorted``
    (one stamp of margin on each side, then the exact test, so rounding in ``t ± max_difference`` loses none).

    Returns:
        (P,) int64 frame indices and (P,) int64 ground-truth indices.
    """
    lo = np.maximum(np.searchsorted(gt_times, frame_times - max_difference, side="left") - 1, 0)
    hi = np.minimum(np.searchsorted(gt_times, frame_times + max_difference, side="right") + 1, len(gt_times))
    counts = np.maximum(hi - lo, 0)
    frames = np.repeat(np.arange(len(frame_times)), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    stamps = np.repeat(lo, counts) + offsets
    close = np.abs(frame_times[frames] - gt_times[stamps]) < max_difference
    return frames[close].astype(np.int64), stamps[close].astype(np.int64)


# --------------------------------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------------------------------


def camera_key(name: str) -> str | None:
    """The Freiburg set-up a sequence name names: ``"rgbd_dataset_freiburg1_xyz"`` or ``"fr1_xyz"`` ->
    ``"freiburg1"``; None if it names none."""
    match = _CAMERA_IN_NAME.search(name)
    return f"freiburg{match.group(1)}" if match else None


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(3, 3) float64 pinhole intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (pixels)."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def camera(
    name: str,
    K: np.ndarray | None = None,
    distortion: np.ndarray | None = None,
    size: tuple[int, int] = SIZE,
) -> tuple[np.ndarray, np.ndarray]:
    """K and distortion of a sequence's colour camera: the Freiburg set-up its name names (:data:`CAMERAS`),
    its K scaled to frames of ``size`` (H, W) when they are not 640x480 (a resized copy;
    :func:`lossvo.geometry.camera.resized_intrinsics`), each replaced by the caller's where given. For a name
    that names no set-up, ``K`` is required and the distortion defaults to zeros (undistorted frames).

    Args:
        name: the sequence's name; K: (3, 3) pixels; distortion: (D,) OpenCV (k1, k2, p1, p2[, k3]).
    Returns:
        (3, 3) float64 K and (D,) float64 distortion.
    Raises:
        DatasetFormatError: if no camera is known for ``name`` and no ``K`` is given.
        UserError: if an override has a wrong shape.
    """
    key = camera_key(name)
    if key is None and K is None:
        raise DatasetFormatError(
            f"sequence {name!r}: unknown camera (the name contains none of freiburg1/2/3, fr1/2/3); "
            "set K= (3x3 intrinsics in pixels) and distortion= (k1 k2 p1 p2 k3)"
        )
    if K is None:
        K = resized_intrinsics(intrinsics(*CAMERAS[str(key)][0]), SIZE, size)
    if distortion is None:
        distortion = np.array(CAMERAS[key][1]) if key else np.zeros(5)
    K_out, d_out = np.asarray(K, dtype=np.float64), np.asarray(distortion, dtype=np.float64)
    if K_out.shape != (3, 3):
        raise UserError(f"sequence {name!r}: K of shape {K_out.shape}, expected (3, 3)")
    if d_out.shape not in ((4,), (5,), (8,), (12,), (14,)):
        raise UserError(f"sequence {name!r}: distortion of shape {d_out.shape}, expected (4,), (5,), ...")
    return K_out, d_out


# --------------------------------------------------------------------------------------------------
# Sequences
# --------------------------------------------------------------------------------------------------


def list_sequences(root: str | os.PathLike) -> list[str]:
    """Names of the sequences under ``root``: its folders holding an ``rgb.txt`` (sorted).

    Raises:
        DatasetFormatError: if ``root`` is not a folder.
    """
    return sorted(
        p.name
        for p in existing_root(root, f"ROOT/<sequence>/{RGB_LIST}").iterdir()
        if (p / RGB_LIST).is_file()
    )


def sequence_dir(root: str | os.PathLike, name: str) -> Path:
    """``root/name``; ``DatasetFormatError`` naming the missing folder and the sequences found."""
    path = existing_root(root, f"ROOT/<sequence>/{RGB_LIST}") / name
    if not path.is_dir():
        found = ", ".join(list_sequences(root)) or "none"
        raise DatasetFormatError(f"{path}: sequence {name!r} not found (found: {found})")
    return path


def load_sequence(
    root: str | os.PathLike,
    name: str,
    require_poses: bool = True,
    K: np.ndarray | None = None,
    distortion: np.ndarray | None = None,
    max_difference: float = MAX_DIFFERENCE_S,
) -> Sequence:
    """Read one sequence's metadata (frame list, ground truth, camera); no frame is decoded.

    Frames are paired with ground-truth rows by :func:`associate`; frames without a pair (outside the ground
    truth's span, in a gap of it longer than ``max_difference``, or outcompeted for a stamp) are left out and
    counted in ``dropped``, so consecutive frames of the result may be further apart than rgb.txt's rate
    (``times`` says by how much). Without a ground-truth file and ``require_poses=False`` every frame is kept
    and ``poses`` is None.

    Args:
        root: the folder holding the sequence folders; name: e.g. ``"rgbd_dataset_freiburg1_xyz"``;
        K, distortion: overrides of the camera (see :func:`camera`); max_difference: seconds.
    Returns:
        The :class:`~lossvo.data.sequence.Sequence`: frames in rgb.txt's order, their times (s), T_w_c at them
        (float64), K, distortion, size (H, W) of the first frame, and the count of dropped frames.
    Raises:
        DatasetFormatError: missing sequence, rgb.txt, listed frame, or groundtruth.txt (when required);
            malformed lines; no frame within ``max_difference`` of a ground-truth stamp; an unknown camera
            without a ``K`` override.
    """
    folder = sequence_dir(root, name)
    rgb_path = folder / RGB_LIST
    if not rgb_path.is_file():
        raise DatasetFormatError(
            f"{rgb_path}: no frame list for sequence {name!r} (expected lines 'timestamp rgb/<stamp>.png')"
        )
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
    return Sequence(
        name,
        [images[k] for k in frame_index],
        times[frame_index],
        gt_poses[gt_index],
        K_seq,
        d_seq,
        size,
        dropped=len(images) - frame_index.size,
    )
