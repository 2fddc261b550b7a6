"""The EuRoC MAV dataset (Burri et al., IJRR 2016) in its own ASL layout.

Layout (one folder per sequence, named as EuRoC names them: ``MH_01_easy``, ``V1_02_medium``)::

    ROOT/<sequence>/mav0/cam0/data.csv              '#timestamp [ns],filename', then one frame a line
    ROOT/<sequence>/mav0/cam0/data/<timestamp>.png  752x480 single-channel frames
    ROOT/<sequence>/mav0/cam0/sensor.yaml           T_BS, resolution, intrinsics, distortion
    ROOT/<sequence>/mav0/state_groundtruth_estimate0/data.csv   200 Hz: timestamp [ns], p_RS_R x y z [m],
                                                    q_RS w x y z, velocity, gyroscope and accelerometer biases

Timestamps are integer nanoseconds (float64 seconds through :func:`ns_to_seconds`). The ground truth is the
body pose T_w_b, so the camera's pose is ``T_w_c(t) = T_w_b(t) @ T_BS``, interpolated at each frame's time
(translation linearly, rotation by slerp); cam0's axes are lossvo's. Frames outside the ground truth or in a
gap wider than ``max_gap`` s are dropped and counted in ``Sequence.dropped``. Distortion is radial-tangential,
as OpenCV's five coefficients. Sources: docs/data.md. Bad input raises one
:class:`~lossvo.data.sequence.DatasetFormatError` line naming the file (and line or YAML key) and what was
expected.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from lossvo.data.sequence import (
    DatasetFormatError,
    Sequence,
    check_choices,
    check_resolution,
    check_rigid,
    existing_root,
    finite_numbers,
    has_ground_truth,
    listed_frames,
    load_mapping,
    pose_matrices,
    positive_resolution,
    text_lines,
    unit_quaternions,
    where,
    yaml_array,
)

CAMERA = "cam0"
GROUND_TRUTH = "state_groundtruth_estimate0"
GROUND_TRUTH_COLUMNS = 17
"""timestamp, p_RS_R (3), q_RS (w, x, y, z), v_RS_R (3), b_w_RS_S (3), b_a_RS_S (3)."""

MAX_GAP_S = 0.02
"""Default largest spacing (s) of the two ground-truth rows a frame is interpolated between (rows are 5 ms
apart at 200 Hz)."""

QUATERNION_TOLERANCE = 1e-3
"""Largest | |q| − 1 | accepted in the ground truth (EuRoC writes 6 decimals)."""

CHOICES = {"camera_model": "pinhole", "distortion_model": "radial-tangential"}
"""The camera and distortion models a ``sensor.yaml`` may name (the ones its reader reads)."""

_NS_PER_S = 1_000_000_000
_DIGITS = re.compile(r"[0-9]+")


# --------------------------------------------------------------------------------------------------
# Timestamps and CSV files
# --------------------------------------------------------------------------------------------------


def ns_to_seconds(ns: np.ndarray) -> np.ndarray:
    """Integer nanoseconds to float64 seconds with one rounding: whole seconds and the nanosecond remainder
    are converted separately (both exactly), so a stamp near 1.4e18 ns is off by at most about one float64
    spacing (2.4e-7 s) instead of the 256 ns lost by converting the integer to float64 first.

    Args:
        ns: (N,) int64 nanoseconds.
    Returns:
        (N,) float64 seconds.
    """
    ns = np.asarray(ns, dtype=np.int64)
    whole, rest = np.divmod(ns, _NS_PER_S)
    return whole.astype(np.float64) + rest.astype(np.float64) / _NS_PER_S


def _csv_rows(path: Path, what: str, columns: int) -> list[tuple[int, list[str]]]:
    """The data lines of an ASL CSV file (lines starting with '#' and empty lines skipped), each with its
    1-based number and its ``columns`` stripped fields."""
    rows = []
    for i, line in text_lines(path, what, comments=True):
        fields = [field.strip() for field in line.split(",")]
        if len(fields) != columns:
            raise DatasetFormatError(
                f"{where(path, i)}: expected {columns} comma-separated columns in {what}, got {len(fields)}"
            )
        rows.append((i, fields))
    if not rows:
        raise DatasetFormatError(f"{path}: no data lines in {what} (expected {columns} columns a line)")
    return rows


def _parse_ns(path: Path, line: int, text: str) -> int:
    if not _DIGITS.fullmatch(text):
        raise DatasetFormatError(
            f"{where(path, line)}: expected a timestamp in integer nanoseconds, got {text!r}"
        )
    return int(text)


def parse_stamps(path: Path, rows: list[tuple[int, list[str]]]) -> np.ndarray:
    """(N,) int64 nanoseconds of the rows' first field, checked strictly increasing, and far enough apart
    to stay distinct as float64 seconds."""
    ns = np.array([_parse_ns(path, i, fields[0]) for i, fields in rows], dtype=np.int64)
    bad = np.flatnonzero(np.diff(ns) <= 0)
    if bad.size:
        k = bad[0] + 1
        raise DatasetFormatError(
            f"{where(path, rows[k][0])}: timestamp {ns[k]} ns does not follow {ns[k - 1]} ns on line "
            f"{rows[k - 1][0]} (expected strictly increasing timestamps)"
        )
    bad = np.flatnonzero(np.diff(ns_to_seconds(ns)) <= 0)
    if bad.size:
        k = bad[0] + 1
        raise DatasetFormatError(
            f"{where(path, rows[k][0])}: timestamp {ns[k]} ns is {ns[k] - ns[k - 1]} ns after line "
            f"{rows[k - 1][0]}'s (expected stamps far enough apart to differ as float64 seconds)"
        )
    return ns


def read_camera_stamps(path: str | os.PathLike) -> tuple[np.ndarray, list[str]]:
    """Read ``cam0/data.csv``: ``timestamp [ns],filename`` a line after a '#' header.

    Returns:
        (N,) int64 nanoseconds, strictly increasing as float64 seconds; N file names relative to
        ``cam0/data``.
    Raises:
        DatasetFormatError: naming the file and line for a missing file, a line without 2 columns, a
            timestamp that is not an integer, that repeats or goes backwards, or an empty file name.
    """
    path = Path(path)
    rows = _csv_rows(path, "camera list", 2)
    for i, (_, name) in rows:
        if not name:
            raise DatasetFormatError(f"{where(path, i)}: empty file name (expected '<timestamp>.png')")
    return parse_stamps(path, rows), [fields[1] for _, fields in rows]


def read_groundtruth_stamps(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """:func:`read_groundtruth` with the times as (M,) int64 nanoseconds, as the file writes them."""
    path = Path(path)
    rows = _csv_rows(path, "ground truth", GROUND_TRUTH_COLUMNS)
    if len(rows) < 2:
        raise DatasetFormatError(f"{path}: one ground-truth row (expected at least 2 to interpolate between)")
    ns = parse_stamps(path, rows)
    values = np.array(
        [finite_numbers(path, i, fields[1:8], "a number", "a finite number") for i, fields in rows],
        dtype=np.float64,
    )
    q_wxyz = unit_quaternions(path, [i for i, _ in rows], values[:, 3:7], "q_RS", QUATERNION_TOLERANCE)
    return ns, pose_matrices(values[:, :3], q_wxyz[:, [1, 2, 3, 0]])  # q_RS is w x y z


def read_groundtruth(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read ``state_groundtruth_estimate0/data.csv``: 17 columns a line, timestamp [ns], p_RS_R (x, y, z) in
    metres, q_RS (w, x, y, z), then velocity and IMU biases (ignored).

    Returns:
        (M,) float64 times in seconds, strictly increasing; (M, 4, 4) float64 body poses T_w_b.
    Raises:
        DatasetFormatError: naming the file and line for a missing file, a line without 17 columns, a
            non-number, a timestamp that repeats or goes backwards, a quaternion far from unit norm, or
            fewer than two rows (nothing to interpolate between).
    """
    ns, T_w_b = read_groundtruth_stamps(path)
    return ns_to_seconds(ns), T_w_b


# --------------------------------------------------------------------------------------------------
# sensor.yaml
# --------------------------------------------------------------------------------------------------


def _read_T_BS(path: Path, data: dict[str, Any]) -> np.ndarray:
    block = data.get("T_BS")
    if not isinstance(block, dict):
        raise DatasetFormatError(
            f"{path}: key 'T_BS' missing or not a mapping "
            "(expected T_BS: {cols: 4, rows: 4, data: [16 numbers]})"
        )
    for key in ("rows", "cols"):
        if key in block and block[key] != 4:
            raise DatasetFormatError(f"{path}: key 'T_BS.{key}': expected 4, got {block[key]!r}")
    T = yaml_array(path, block, "data", (16,), "the 16 numbers of T_BS, row-major").reshape(4, 4)
    check_rigid(path, T, "T_BS")
    return T


def read_sensor(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """Read a camera's ``sensor.yaml``.

    Returns:
        K: (3, 3) float64 from ``intrinsics: [fu, fv, cu, cv]`` (pixels);
        distortion: (4,) float64 ``distortion_coefficients`` (k1, k2, p1, p2), radial-tangential;
        T_BS: (4, 4) float64 pose of the camera in the body (IMU) frame;
        size: (H, W) in pixels, from ``resolution: [W, H]``.
    Raises:
        DatasetFormatError: naming the file and the key for a missing file, invalid YAML, a missing or
            malformed key, a camera model other than pinhole / radial-tangential, or a T_BS that is not a
            rigid transform (rotation not orthonormal, det != 1, last row not 0 0 0 1).
    """
    path = Path(path)
    data = load_mapping(path, "T_BS, resolution and intrinsics")
    check_choices(path, data, CHOICES)
    fu, fv, cu, cv = yaml_array(path, data, "intrinsics", (4,), "[fu, fv, cu, cv] in pixels")
    if fu <= 0 or fv <= 0:
        raise DatasetFormatError(f"{path}: key 'intrinsics': expected positive focal lengths, got {fu}, {fv}")
    distortion = yaml_array(path, data, "distortion_coefficients", (4,), "[k1, k2, p1, p2]")
    width, height = yaml_array(path, data, "resolution", (2,), "[width, height] in pixels")
    size = positive_resolution(path, width, height, data["resolution"])
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    return K, distortion, _read_T_BS(path, data), size


# --------------------------------------------------------------------------------------------------
# Poses at the frames' times
# --------------------------------------------------------------------------------------------------


def bracket(
    gt_ns: np.ndarray, ns: np.ndarray, max_gap: float = MAX_GAP_S
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ground-truth rows each stamp lies between, computed in integer nanoseconds (as float64 seconds,
    stamps near 1.4e9 s carry up to 0.24 µs of rounding: 5e-5 of a 5 ms interval).

    Args:
        gt_ns: (M,) int64 strictly increasing nanoseconds, M >= 2; ns: (N,) int64 nanoseconds;
        max_gap: the largest spacing (s) of two bracketing rows.
    Returns:
        index: (N,) int, the row at or before each stamp (``index + 1`` is the row after);
        fraction: (N,) float64 in [0, 1], where the stamp lies between the two rows;
        keep: (N,) bool, False for stamps outside ``[gt_ns[0], gt_ns[-1]]`` or between rows more than
            ``max_gap`` apart (index and fraction are then meaningless).
    """
    gt_ns, ns = np.asarray(gt_ns, dtype=np.int64), np.asarray(ns, dtype=np.int64)
    index = np.clip(np.searchsorted(gt_ns, ns, side="right") - 1, 0, len(gt_ns) - 2)
    spacing = gt_ns[index + 1] - gt_ns[index]
    fraction = np.clip((ns - gt_ns[index]) / spacing, 0.0, 1.0)
    keep = (ns >= gt_ns[0]) & (ns <= gt_ns[-1]) & (spacing <= max_gap * _NS_PER_S)
    return index, fraction, keep


def interpolate_poses(T0: np.ndarray, T1: np.ndarray, fraction: np.ndarray) -> np.ndarray:
    """Poses between T0 and T1: translation linear, rotation along the shortest geodesic (slerp),
    ``R = R0 exp(f log(R0ᵀ R1))``.

    Args:
        T0, T1: (N, 4, 4) float64 poses; fraction: (N,) in [0, 1] (0 gives T0, 1 gives T1).
    Returns:
        (N, 4, 4) float64.
    """
    f = np.asarray(fraction, dtype=np.float64)[:, None]
    R0 = Rotation.from_matrix(T0[:, :3, :3])
    step = (R0.inv() * Rotation.from_matrix(T1[:, :3, :3])).as_rotvec()
    poses = np.zeros((len(f), 4, 4))
    poses[:, :3, :3] = (R0 * Rotation.from_rotvec(f * step)).as_matrix()
    poses[:, :3, 3] = (1.0 - f) * T0[:, :3, 3] + f * T1[:, :3, 3]
    poses[:, 3, 3] = 1.0
    return poses


def camera_poses(
    gt_ns: np.ndarray, T_w_b: np.ndarray, T_BS: np.ndarray, ns: np.ndarray, max_gap: float = MAX_GAP_S
) -> tuple[np.ndarray, np.ndarray]:
    """Camera poses ``T_w_c(t) = T_w_b(t) @ T_BS`` at the frames' stamps, T_w_b interpolated (see
    :func:`bracket`, :func:`interpolate_poses`).

    Args:
        gt_ns: (M,) int64 ground-truth stamps in nanoseconds; T_w_b: (M, 4, 4) body poses; T_BS: (4, 4)
            camera in body; ns: (N,) int64 frame stamps in nanoseconds; max_gap: see :func:`bracket`.
    Returns:
        (K, 4, 4) float64 T_w_c of the kept frames, and the (N,) bool mask of the kept frames (K of them).
    """
    index, fraction, keep = bracket(gt_ns, ns, max_gap)
    index, fraction = index[keep], fraction[keep]
    T_w_b_t = interpolate_poses(T_w_b[index], T_w_b[index + 1], fraction)
    return T_w_b_t @ np.asarray(T_BS, dtype=np.float64), keep


# --------------------------------------------------------------------------------------------------
# Sequences
# --------------------------------------------------------------------------------------------------


def list_sequences(root: str | os.PathLike) -> list[str]:
    """Names of the sequences under ``root`` (folders holding ``mav0``), sorted."""
    folder = existing_root(root, "ROOT/<sequence>/mav0")
    return sorted(p.name for p in folder.iterdir() if (p / "mav0").is_dir())


def sequence_dir(root: str | os.PathLike, name: str) -> Path:
    """``root/name/mav0``; DatasetFormatError naming the missing folder and the sequences found."""
    root = Path(root).expanduser()
    path = root / name / "mav0"
    if not path.is_dir():
        found = ", ".join(list_sequences(root)) or "none"
        raise DatasetFormatError(
            f"{path}: sequence {name!r} not found (expected ROOT/<name>/mav0; found: {found})"
        )
    return path


def load_sequence(
    root: str | os.PathLike, name: str, require_poses: bool = True, max_gap: float = MAX_GAP_S
) -> Sequence:
    """Read and check one sequence's metadata (frame list, camera, ground truth); no image is decoded.

    Frames outside the ground truth's span, or between ground-truth rows more than ``max_gap`` seconds
    apart, are dropped and counted in ``dropped``; the datamodule cuts windows where frames were dropped.

    Args:
        root: the folder holding the sequences; name: a sequence as EuRoC names it (``"V1_02_medium"``);
        require_poses: raise when the ground truth is missing (else the sequence has ``poses=None``).
    Returns:
        Sequence with T_w_c of cam0 (``T_w_b(t) @ T_BS``), K, distortion (k1, k2, p1, p2, 0), size (H, W).
    Raises:
        DatasetFormatError: an unknown sequence (naming those found), a missing or malformed file, a frame
            whose size differs from sensor.yaml's resolution, or no frame within the ground truth's span.
    """
    mav0 = sequence_dir(root, name)
    gt_path = mav0 / GROUND_TRUTH / "data.csv"
    return asl_sequence(
        name, mav0 / CAMERA, gt_path, read_sensor, read_groundtruth_stamps, require_poses, max_gap
    )


def asl_sequence(
    name: str,
    camera: Path,
    gt_path: Path,
    read_sensor: Callable[[Path], tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]],
    read_groundtruth: Callable[[Path], tuple[np.ndarray, np.ndarray]],
    require_poses: bool,
    max_gap: float,
) -> Sequence:
    """A sequence of an ASL camera folder (``data.csv``, ``data/``, ``sensor.yaml``: (K, distortion, T_BS,
    size)) and a ground truth of body poses T_w_b (stamps in ns): T_w_c = ``T_w_b(t) @ T_BS`` at the frames'
    stamps (:func:`camera_poses`), frames outside it dropped; DatasetFormatError naming both files where
    none is kept."""
    csv_path = camera / "data.csv"
    ns, names = read_camera_stamps(csv_path)
    times = ns_to_seconds(ns)
    images = listed_frames(csv_path, camera / "data", names)
    K, distortion, T_BS, size = read_sensor(camera / "sensor.yaml")
    check_resolution(images[0], size, camera / "sensor.yaml")
    distortion = np.append(distortion, np.zeros(5 - len(distortion)))  # OpenCV's (k1, k2, p1, p2, k3)
    if not has_ground_truth(gt_path, name, require_poses):
        return Sequence(name, images, times, None, K, distortion, size)
    gt_ns, T_w_b = read_groundtruth(gt_path)
    poses, keep = camera_poses(gt_ns, T_w_b, T_BS, ns, max_gap)
    if not keep.any():
        raise DatasetFormatError(
            f"{gt_path}: no frame of {csv_path} within the ground truth's span "
            f"[{gt_ns[0]}, {gt_ns[-1]}] ns without gaps over {max_gap} s "
            f"(frames span [{ns[0]}, {ns[-1]}] ns)"
        )
    kept = [path for path, k in zip(images, keep, strict=True) if k]
    return Sequence(name, kept, times[keep], poses, K, distortion, size, dropped=int((~keep).sum()))
