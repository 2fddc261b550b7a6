"""The MIMIR-UW layout (``ROOT/<env>/auv0/<track>/`` or ``ROOT/<env>/<track>/auv0/``, with
``rgb/<camera>/{data.csv, data/, sensor.yaml}`` and ``pose_groundtruth/data.csv``; docs/data.md): EuRoC's
ASL files (:mod:`lossvo.data.euroc`) with NED body poses, the camera's read as
``ned_to_camera(T_w_b(t) @ T_BS)``.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from lossvo.data import euroc
from lossvo.data.sequence import (
    DatasetFormatError,
    Sequence,
    check_rigid,
    find_sequences,
    load_mapping,
    sequence_folder,
    text_lines,
    where,
    yaml_array,
    yaml_resolution,
)
from lossvo.data.tartanair import ned_to_camera

CAMERA = "cam0"
GROUND_TRUTH = "pose_groundtruth"
GROUND_TRUTH_COLUMNS = 8
"""At least: timestamp [ns], position x y z [m], orientation q w x y z (the study's loader's order)."""
_COLUMNS = "'timestamp, tx, ty, tz, qw, qx, qy, qz'"
SHAPES = ("<env>/auv0/<track>", "<env>/<track>/auv0")
"""The two orders of a track's folders (the README's, the study's)."""

MAX_GAP_S = 0.1
"""Default largest spacing (s) of the two ground-truth rows a frame is interpolated between (MIMIR documents
no ground-truth rate)."""


def _groundtruth_rows(path: Path) -> list[tuple[int, list[str]]]:
    """The line numbers and stripped fields of the ground truth's data lines ('#' lines and a first line
    starting with ``timestamp`` left out), each with the first's count of columns, at least 8."""
    rows: list[tuple[int, list[str]]] = []
    for i, line in text_lines(path, "ground truth", comments=True):
        text = line.strip()
        if not rows and text.lower().startswith("timestamp"):
            continue
        fields = [field.strip() for field in text.split(",")]
        if rows and len(fields) != len(rows[0][1]):
            expected = f"{len(rows[0][1])} comma-separated columns like line {rows[0][0]}"
        elif len(fields) < GROUND_TRUTH_COLUMNS:
            expected = f"at least {GROUND_TRUTH_COLUMNS} comma-separated columns {_COLUMNS}"
        else:
            rows.append((i, fields))
            continue
        raise DatasetFormatError(f"{where(path, i)}: expected {expected}, got {len(fields)}")
    if len(rows) < 2:
        raise DatasetFormatError(
            f"{path}: {len(rows)} ground-truth rows (expected at least 2 lines {_COLUMNS} "
            "to interpolate between)"
        )
    return rows


def read_groundtruth(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """``pose_groundtruth/data.csv`` (``timestamp [ns], tx, ty, tz, qw, qx, qy, qz[, ...]``): (M,) int64
    nanoseconds and (M, 4, 4) float64 body poses T_w_b, NED axes."""
    path = Path(path)
    return euroc.body_poses(path, _groundtruth_rows(path), "(qw qx qy qz)")


def read_sensor(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """A camera's ``sensor.yaml``: K (3, 3) ``intrinsics`` in pixels, distortion (4,) or (5,) (k1, k2, p1,
    p2[, k3]), T_BS (4, 4) the camera's pose in the body frame (body axes for both), size (H, W) from
    ``resolution``."""
    path = Path(path)
    data = load_mapping(path, "T_BS, resolution and intrinsics", euroc.CHOICES)
    K = yaml_array(
        path, data, "intrinsics", (3, 3), "a 3x3 list [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels"
    )
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise DatasetFormatError(
            f"{path}: key 'intrinsics': expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, "
            f"got {data['intrinsics']!r}"
        )
    n = 4 if len(data.get("distortion_coefficients") or []) == 4 else 5
    names = ", ".join(["k1", "k2", "p1", "p2", "k3"][:n])
    distortion = yaml_array(path, data, "distortion_coefficients", (n,), f"[{names}]")
    size = yaml_resolution(path, data)
    T_BS = yaml_array(path, data, "T_BS", (4, 4), "a 4x4 list, the camera's pose in the body frame")
    check_rigid(path, T_BS, "T_BS")
    return K, distortion, T_BS, size


def list_sequences(root: str | os.PathLike, camera: str = CAMERA) -> list[str]:
    """Names of the tracks under ``root`` that hold ``rgb/<camera>`` (either order of :data:`SHAPES`)."""
    return find_sequences(root, f"rgb/{camera}", *SHAPES)


def load_sequence(
    root: str | os.PathLike,
    name: str,
    require_poses: bool = True,
    camera: str = CAMERA,
    max_gap: float = MAX_GAP_S,
) -> Sequence:
    """One track's metadata, checked, as :func:`lossvo.data.euroc.asl_sequence` reads it, T_w_c in lossvo's
    axes; ``camera``: ``cam0``, ``cam1`` or ``cam2``. No frame is decoded."""
    folder = sequence_folder(root, name, f"rgb/{camera}", *SHAPES)
    gt_path = folder / GROUND_TRUTH / "data.csv"
    seq = euroc.asl_sequence(
        name, folder / "rgb" / camera, gt_path, read_sensor, read_groundtruth, require_poses, max_gap
    )
    return seq if seq.poses is None else replace(seq, poses=ned_to_camera(seq.poses))
