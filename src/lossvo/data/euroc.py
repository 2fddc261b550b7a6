"""The EuRoC MAV layout, ASL's (``ROOT/<sequence>/mav0/`` with ``cam0/{data.csv, data/, sensor.yaml}`` and
``state_groundtruth_estimate0/data.csv``; docs/data.md): integer-nanosecond stamps, ``sensor.yaml``, and the
camera's poses ``T_w_b(t) @ T_BS`` interpolated at the frames' times. :mod:`lossvo.data.mimir` shares the
ASL parts.
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
    check_increasing,
    check_rigid,
    find_sequences,
    finite_numbers,
    has_ground_truth,
    listed_frames,
    load_mapping,
    png_size,
    quaternion_poses,
    sequence_folder,
    text_lines,
    where,
    yaml_array,
    yaml_resolution,
)

CAMERA = "cam0"
GROUND_TRUTH = "state_groundtruth_estimate0"
GROUND_TRUTH_COLUMNS = 17
"""timestamp, p_RS_R (3), q_RS (w, x, y, z), v_RS_R (3), b_w_RS_S (3), b_a_RS_S (3)."""

MAX_GAP_S = 0.02
"""Default largest spacing (s) of the two ground-truth rows a frame is interpolated between (200 Hz rows)."""

QUATERNION_TOLERANCE = 1e-3
"""Largest | |q| − 1 | accepted in the ground truth (EuRoC writes 6 decimals)."""

CHOICES = {"camera_model": "pinhole", "distortion_model": "radial-tangential"}
"""The camera and distortion models a ``sensor.yaml`` may name (the ones read)."""

_NS_PER_S = 1_000_000_000
_DIGITS = re.compile(r"[0-9]+")


def ns_to_seconds(ns: np.ndarray) -> np.ndarray:
    """(N,) int64 nanoseconds as float64 seconds, rounded once (whole seconds and the remainder are
    converted apart: converting 1.4e18 ns to float64 first would lose 256 ns)."""
    whole, rest = np.divmod(np.asarray(ns, dtype=np.int64), _NS_PER_S)
    return whole.astype(np.float64) + rest.astype(np.float64) / _NS_PER_S


def _csv_rows(path: Path, what: str, columns: int) -> list[tuple[int, list[str]]]:
    """The line numbers and ``columns`` stripped fields of an ASL CSV file's data lines ('#' lines out)."""
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


def parse_stamps(path: Path, rows: list[tuple[int, list[str]]]) -> np.ndarray:
    """(N,) int64 nanoseconds of the rows' first fields, strictly increasing even as float64 seconds."""
    for i, fields in rows:
        if not _DIGITS.fullmatch(fields[0]):
            raise DatasetFormatError(
                f"{where(path, i)}: expected a timestamp in integer nanoseconds, got {fields[0]!r}"
            )
    ns = np.array([int(fields[0]) for _, fields in rows], dtype=np.int64)
    check_increasing(path, [i for i, _ in rows], ns, " ns")
    bad = np.flatnonzero(np.diff(ns_to_seconds(ns)) <= 0)
    if bad.size:
        k = bad[0] + 1
        raise DatasetFormatError(
            f"{where(path, rows[k][0])}: timestamp {ns[k]} ns is {ns[k] - ns[k - 1]} ns after line "
            f"{rows[k - 1][0]}'s (expected stamps far enough apart to differ as float64 seconds)"
        )
    return ns


def body_poses(path: Path, rows: list[tuple[int, list[str]]], label: str) -> tuple[np.ndarray, np.ndarray]:
    """(M,) int64 nanoseconds and (M, 4, 4) float64 body poses T_w_b of ground-truth rows
    ``timestamp, tx, ty, tz, qw, qx, qy, qz, ...`` (``label``: the quaternion's name in an error)."""
    ns = parse_stamps(path, rows)
    values = np.array([finite_numbers(path, i, f[1:8], "a number", "a finite number") for i, f in rows])
    lines = [i for i, _ in rows]
    T_w_b = quaternion_poses(path, lines, values[:, :3], values[:, [4, 5, 6, 3]], label, QUATERNION_TOLERANCE)
    return ns, T_w_b


def read_camera_stamps(path: str | os.PathLike) -> tuple[np.ndarray, list[str]]:
    """``cam0/data.csv`` (``timestamp [ns],filename`` lines): (N,) int64 nanoseconds and the N file names
    relative to ``cam0/data``."""
    path = Path(path)
    rows = _csv_rows(path, "camera list", 2)
    for i, (_, name) in rows:
        if not name:
            raise DatasetFormatError(f"{where(path, i)}: empty file name (expected '<timestamp>.png')")
    return parse_stamps(path, rows), [fields[1] for _, fields in rows]


def read_groundtruth(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """``state_groundtruth_estimate0/data.csv`` (:data:`GROUND_TRUTH_COLUMNS`; velocity and biases
    ignored): (M,) int64 nanoseconds, M >= 2, and (M, 4, 4) float64 body poses T_w_b."""
    path = Path(path)
    rows = _csv_rows(path, "ground truth", GROUND_TRUTH_COLUMNS)
    if len(rows) < 2:
        raise DatasetFormatError(f"{path}: one ground-truth row (expected at least 2 to interpolate between)")
    return body_poses(path, rows, "q_RS")


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
    """A camera's ``sensor.yaml``: K (3, 3) from ``intrinsics: [fu, fv, cu, cv]`` (pixels), distortion (4,)
    (k1, k2, p1, p2), T_BS (4, 4) the camera's pose in the body frame, size (H, W) from ``resolution``."""
    path = Path(path)
    data = load_mapping(path, "T_BS, resolution and intrinsics", CHOICES)
    fu, fv, cu, cv = yaml_array(path, data, "intrinsics", (4,), "[fu, fv, cu, cv] in pixels")
    if fu <= 0 or fv <= 0:
        raise DatasetFormatError(f"{path}: key 'intrinsics': expected positive focal lengths, got {fu}, {fv}")
    distortion = yaml_array(path, data, "distortion_coefficients", (4,), "[k1, k2, p1, p2]")
    size = yaml_resolution(path, data)
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    return K, distortion, _read_T_BS(path, data), size


def interpolate_poses(T0: np.ndarray, T1: np.ndarray, fraction: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses ``fraction`` (N,) of the way from T0 to T1 (N, 4, 4): translation linear, rotation
    along the geodesic (slerp), ``R = R0 exp(f log(R0ᵀ R1))``."""
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
    """Camera poses ``T_w_b(t) @ T_BS`` at the frames' stamps, T_w_b interpolated between the rows around
    each (found in integer nanoseconds).

    Args:
        gt_ns: (M,) int64 strictly increasing, M >= 2; T_w_b: (M, 4, 4); T_BS: (4, 4); ns: (N,) int64.
    Returns:
        (K, 4, 4) float64 T_w_c of the frames kept, and their (N,) bool mask: the frames within the ground
        truth's span, between rows at most ``max_gap`` s apart.
    """
    index = np.clip(np.searchsorted(gt_ns, ns, side="right") - 1, 0, len(gt_ns) - 2)
    spacing = gt_ns[index + 1] - gt_ns[index]
    keep = (ns >= gt_ns[0]) & (ns <= gt_ns[-1]) & (spacing <= max_gap * _NS_PER_S)
    index = index[keep]
    fraction = np.clip((ns[keep] - gt_ns[index]) / spacing[keep], 0.0, 1.0)
    T_w_b_t = interpolate_poses(T_w_b[index], T_w_b[index + 1], fraction)
    return T_w_b_t @ np.asarray(T_BS, dtype=np.float64), keep


def list_sequences(root: str | os.PathLike) -> list[str]:
    """Names of the sequences under ``root`` (folders holding ``mav0``), sorted."""
    return find_sequences(root, "mav0", "<sequence>")


def load_sequence(
    root: str | os.PathLike, name: str, require_poses: bool = True, max_gap: float = MAX_GAP_S
) -> Sequence:
    """One sequence's metadata, checked: cam0's frames, K and distortion (k1, k2, p1, p2, 0), T_w_c =
    ``T_w_b(t) @ T_BS``; frames outside the ground truth or in a gap of it wider than ``max_gap`` s are
    dropped and counted. No frame is decoded."""
    mav0 = sequence_folder(root, name, "mav0", "<sequence>") / "mav0"
    gt_path = mav0 / GROUND_TRUTH / "data.csv"
    return asl_sequence(name, mav0 / CAMERA, gt_path, read_sensor, read_groundtruth, require_poses, max_gap)


def asl_sequence(
    name: str,
    camera: Path,
    gt_path: Path,
    read_sensor: Callable[[Path], tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]],
    read_groundtruth: Callable[[Path], tuple[np.ndarray, np.ndarray]],
    require_poses: bool,
    max_gap: float,
) -> Sequence:
    """A sequence of an ASL camera folder (``data.csv``, ``data/``, ``sensor.yaml``) and a ground truth of
    body poses T_w_b (stamps in ns): T_w_c = ``T_w_b(t) @ T_BS`` at the frames' stamps
    (:func:`camera_poses`), frames outside it dropped."""
    csv_path, yaml_path = camera / "data.csv", camera / "sensor.yaml"
    ns, names = read_camera_stamps(csv_path)
    times = ns_to_seconds(ns)
    images = listed_frames(csv_path, camera / "data", names)
    K, distortion, T_BS, size = read_sensor(yaml_path)
    found = png_size(images[0])
    if found != size:
        raise DatasetFormatError(
            f"{images[0]}: frame of {found[1]}x{found[0]} pixels, but {yaml_path} key 'resolution' says "
            f"{size[1]}x{size[0]}"
        )
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
