"""The MIMIR-UW underwater dataset (Álvarez-Tuñón et al., IROS 2023), the study's dataset, in its own layout.

Layout (https://github.com/remaro-network/MIMIR-UW, "Dataset structure")::

    ROOT/<env>/auv0/<track>/rgb/cam0/data/<timestamp>.png    frames (cameras cam0, cam1, cam2)
    ROOT/<env>/auv0/<track>/rgb/cam0/data.csv                the frame list, EuRoC's ASL format
    ROOT/<env>/auv0/<track>/rgb/cam0/sensor.yaml             T_BS, rate_hz, resolution, K, distortion
    ROOT/<env>/auv0/<track>/pose_groundtruth/data.csv        the ground truth

A sequence is named by its path under ROOT (``"SeaFloor/auv0/track0"``; ``<env>/<track>/auv0`` is read too).
Timestamps are integer nanoseconds; a ground-truth row is ``timestamp, tx, ty, tz, qw, qx, qy, qz`` (further
columns ignored): the body pose T_w_b in AirSim's NED world, body axes x forward, y right, z down. The
camera's pose is ``ned_to_camera(T_w_b(t) @ T_BS)`` (:func:`lossvo.data.tartanair.ned_to_camera`), T_w_b
interpolated at each frame's time (:func:`lossvo.data.euroc.camera_poses`); frames outside the ground truth or
in a gap wider than ``max_gap`` are dropped and counted in ``Sequence.dropped``. Where each convention comes
from: docs/data.md. Bad input raises one :class:`~lossvo.data.sequence.DatasetFormatError` line naming the
file (and the 1-based line or the YAML key) and what was expected.
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
    check_choices,
    check_rigid,
    existing_root,
    finite_numbers,
    load_mapping,
    pose_matrices,
    positive_resolution,
    text_lines,
    unit_quaternions,
    where,
    yaml_array,
)
from lossvo.data.tartanair import ned_to_camera

CAMERA = "cam0"
GROUND_TRUTH = "pose_groundtruth"
GROUND_TRUTH_COLUMNS = 8
"""At least: timestamp [ns], position x y z [m], orientation q w x y z (the study's loader's order)."""

MAX_GAP_S = 0.1
"""Default largest spacing (s) of the two ground-truth rows a frame is interpolated between: a few rows at any
rate of 30 Hz or more (MIMIR documents no ground-truth rate)."""

QUATERNION_TOLERANCE = 1e-3
"""Largest | ||q|| - 1 | accepted in the ground truth."""


# --------------------------------------------------------------------------------------------------
# Ground truth
# --------------------------------------------------------------------------------------------------


def _groundtruth_rows(path: Path) -> list[tuple[int, list[str]]]:
    """The data lines of ``pose_groundtruth/data.csv`` with their 1-based numbers and stripped fields: '#'
    lines, empty lines and a first line starting with ``timestamp`` skipped; every line with the first line's
    count of columns, at least :data:`GROUND_TRUTH_COLUMNS`."""
    rows: list[tuple[int, list[str]]] = []
    for i, line in text_lines(path, "ground truth", comments=True):
        text = line.strip()
        if not rows and text.lower().startswith("timestamp"):
            continue
        fields = [field.strip() for field in text.split(",")]
        count = len(rows[0][1]) if rows else GROUND_TRUTH_COLUMNS
        if len(fields) < GROUND_TRUTH_COLUMNS or (rows and len(fields) != count):
            expected = (
                f"{count} comma-separated columns like line {rows[0][0]}"
                if rows
                else (
                    f"at least {GROUND_TRUTH_COLUMNS} comma-separated columns "
                    "'timestamp, tx, ty, tz, qw, qx, qy, qz'"
                )
            )
            raise DatasetFormatError(f"{where(path, i)}: expected {expected}, got {len(fields)}")
        rows.append((i, fields))
    if len(rows) < 2:
        raise DatasetFormatError(
            f"{path}: {len(rows)} ground-truth rows (expected at least 2 lines "
            "'timestamp, tx, ty, tz, qw, qx, qy, qz' to interpolate between)"
        )
    return rows


def read_groundtruth(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read ``pose_groundtruth/data.csv``: lines ``timestamp [ns], tx, ty, tz, qw, qx, qy, qz[, ...]``.

    Returns:
        (M,) int64 stamps in nanoseconds, strictly increasing; (M, 4, 4) float64 body poses T_w_b with NED
        axes (world and body), quaternions normalised.
    Raises:
        DatasetFormatError: naming the file and line for a missing file, fewer than two rows, a line with
            fewer than 8 columns or another count than the first, a non-number, a timestamp that repeats or
            goes backwards, or a quaternion far from unit norm.
    """
    path = Path(path)
    rows = _groundtruth_rows(path)
    ns = euroc.parse_stamps(path, rows)
    values = np.array(
        [
            finite_numbers(path, i, fields[1:GROUND_TRUTH_COLUMNS], "a number", "a finite number")
            for i, fields in rows
        ],
        dtype=np.float64,
    )
    q_wxyz = unit_quaternions(
        path, [i for i, _ in rows], values[:, 3:7], "(qw qx qy qz)", QUATERNION_TOLERANCE
    )
    return ns, pose_matrices(values[:, :3], q_wxyz[:, [1, 2, 3, 0]])


# --------------------------------------------------------------------------------------------------
# sensor.yaml
# --------------------------------------------------------------------------------------------------


def read_sensor(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """Read a camera's ``sensor.yaml`` (the README's keys).

    Returns:
        K: (3, 3) float64 ``intrinsics`` in pixels;
        distortion: (5,) float64 OpenCV (k1, k2, p1, p2, k3) from ``distortion_coefficients`` (4 or 5 of
            them, padded with 0);
        T_BS: (4, 4) float64 pose of the camera in the body frame, both with body (x forward, y right, z down)
            axes;
        size: (H, W) in pixels, from ``resolution: [W, H]``.
    Raises:
        DatasetFormatError: naming the file and the key for a missing file, invalid YAML, a missing or
            malformed key, a model other than pinhole / radial-tangential, a K that is not
            ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` with positive focal lengths, or a T_BS that is not
            rigid.
    """
    path = Path(path)
    data = load_mapping(path, "T_BS, resolution and intrinsics")
    check_choices(path, data, euroc.CHOICES)
    K = yaml_array(
        path, data, "intrinsics", (3, 3), "a 3x3 list [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels"
    )
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise DatasetFormatError(
            f"{path}: key 'intrinsics': expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, "
            f"got {data['intrinsics']!r}"
        )
    if len(data.get("distortion_coefficients") or []) == 4:
        distortion = np.append(
            yaml_array(path, data, "distortion_coefficients", (4,), "[k1, k2, p1, p2]"), 0.0
        )
    else:
        distortion = yaml_array(path, data, "distortion_coefficients", (5,), "[k1, k2, p1, p2, k3]")
    width, height = yaml_array(path, data, "resolution", (2,), "[width, height] in pixels")
    size = positive_resolution(path, width, height, data["resolution"])
    T_BS = yaml_array(path, data, "T_BS", (4, 4), "a 4x4 list, the camera's pose in the body frame")
    check_rigid(path, T_BS, "T_BS")
    return K, distortion, T_BS, size


# --------------------------------------------------------------------------------------------------
# Sequences
# --------------------------------------------------------------------------------------------------


def list_sequences(root: str | os.PathLike, camera: str = CAMERA) -> list[str]:
    """Names of the tracks under ``root`` that hold ``rgb/<camera>``: ``<env>/auv0/<track>`` (the README's
    order) or ``<env>/<track>/auv0`` (the study's), sorted.

    Raises:
        DatasetFormatError: if ``root`` is not a folder.
    """
    base = existing_root(root, "ROOT/<env>/auv0/<track>/rgb")
    found = [*base.glob(f"*/auv0/*/rgb/{camera}"), *base.glob(f"*/*/auv0/rgb/{camera}")]
    return sorted({p.parent.parent.relative_to(base).as_posix() for p in found if p.is_dir()})


def sequence_dir(root: str | os.PathLike, name: str, camera: str = CAMERA) -> Path:
    """``root/name``, checked to hold ``rgb/<camera>``; DatasetFormatError naming the missing folder and the
    sequences found."""
    path = existing_root(root, "ROOT/<env>/auv0/<track>/rgb") / name
    if not (path / "rgb" / camera).is_dir():
        found = ", ".join(list_sequences(root, camera)) or "none"
        raise DatasetFormatError(
            f"{path / 'rgb' / camera}: sequence {name!r} not found "
            f"(expected ROOT/<env>/auv0/<track>/rgb/{camera}; found: {found})"
        )
    return path


def load_sequence(
    root: str | os.PathLike,
    name: str,
    require_poses: bool = True,
    camera: str = CAMERA,
    max_gap: float = MAX_GAP_S,
) -> Sequence:
    """Read and check one sequence's metadata (frame list, camera, ground truth); no frame is decoded.

    Args:
        root: the folder holding the environments; name: ``"<env>/auv0/<track>"``; require_poses: raise when
            the ground truth is missing (else the sequence has ``poses=None`` and keeps every frame);
        camera: ``cam0``, ``cam1`` or ``cam2``; max_gap: see :func:`lossvo.data.euroc.bracket` (s).
    Returns:
        Sequence with T_w_c = ``ned_to_camera(T_w_b(t) @ T_BS)`` in lossvo's convention, K, distortion
        (k1, k2, p1, p2, k3), size (H, W); frames outside the ground truth's span dropped and counted.
    Raises:
        DatasetFormatError: an unknown sequence (naming those found), a missing or malformed file, a frame
            whose size differs from ``resolution``, or no frame within the ground truth's span.
    """
    folder = sequence_dir(root, name, camera)
    gt_path = folder / GROUND_TRUTH / "data.csv"
    seq = euroc.asl_sequence(
        name, folder / "rgb" / camera, gt_path, read_sensor, read_groundtruth, require_poses, max_gap
    )
    return seq if seq.poses is None else replace(seq, poses=ned_to_camera(seq.poses))
