"""The data contract every dataset reader returns: one sequence's frames, timestamps, camera poses and camera.

Readers (``kitti``, ``tum``, ``euroc``, ``tartanair``, ``mimir``) read a dataset in its own layout and convert
at the reader, so that everything after them sees one convention: poses are 4x4 camera-to-world matrices
T_w_c in float64 with the camera's x right, y down, z forward (KITTI's and OpenCV's), timestamps are seconds,
K and the distortion are those of the frames as stored on disk (before any resize).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from lossvo.checks import is_integer, is_number
from lossvo.console import UserError


class DatasetFormatError(UserError):
    """A file or folder that does not follow a dataset's layout: the message names the file (and line or key)
    and what was expected."""


def where(path: Path, line: int | None = None) -> str:
    """``path`` or ``path:line`` (1-based) for an error message."""
    return f"{path}:{line}" if line is not None else str(path)


def finite_numbers(
    path: Path,
    line: int,
    fields: list[str],
    expected: str,
    finite: str | None = None,
    error: type[DatasetFormatError] = DatasetFormatError,
) -> list[float]:
    """``fields`` (the text of line ``line`` of ``path``) as finite floats.

    Raises:
        error: ``<path>:<line>: expected <expected>, got '<field>'`` at the first field that is no number,
            and the same with ``finite`` (default ``expected``) at the first that is not finite.
    """
    values = []
    for text in fields:
        try:
            value = float(text)
        except ValueError:
            raise error(f"{where(path, line)}: expected {expected}, got {text!r}") from None
        if not np.isfinite(value):
            raise error(f"{where(path, line)}: expected {finite or expected}, got {text!r}")
        values.append(value)
    return values


def text_lines(
    path: Path, what: str, comments: bool = False, error: type[DatasetFormatError] = DatasetFormatError
) -> list[tuple[int, str]]:
    """The non-empty lines of a text file with their numbers (from 1), '#' comments left out where
    ``comments``; ``error`` ``<path>: cannot read <what> (<reason>)`` when the file cannot be read."""
    try:
        lines = path.read_text().splitlines()
    except OSError as e:
        raise error(f"{path}: cannot read {what} ({e.strerror})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: cannot read {what} (not a text file)") from None
    rows = [(i, line) for i, line in enumerate(lines, start=1) if line.strip()]
    return [(i, line) for i, line in rows if not (comments and line.lstrip().startswith("#"))]


def listed_frames(list_path: Path, folder: Path, names: list[str]) -> list[Path]:
    """``folder / name`` for each name of a frame list; DatasetFormatError at the list's line (its data
    lines: '#' comments left out) of the first that is no file."""
    paths = [folder / name for name in names]
    k = next((k for k, path in enumerate(paths) if not path.is_file()), None)
    if k is not None:
        line = text_lines(list_path, "frame list", comments=True)[k][0]
        raise DatasetFormatError(
            f"{where(list_path, line)}: frame {names[k]!r} not found: {paths[k]} does not exist"
        )
    return paths


def has_ground_truth(
    path: Path,
    name: str,
    require: bool,
    what: str = "ground truth",
    error: type[DatasetFormatError] = DatasetFormatError,
) -> bool:
    """Whether a sequence's ground-truth file exists; ``error`` naming it where it is missing and
    ``require``."""
    if require and not path.is_file():
        raise error(f"{path}: no {what} for sequence {name} (needed for training/evaluation)")
    return path.is_file()


def existing_root(root: str | os.PathLike, layout: str) -> Path:
    """``root`` as a Path (``~`` expanded); DatasetFormatError naming it and the expected ``layout`` (e.g.
    ``"ROOT/<sequence>/mav0"``) when it is no folder."""
    path = Path(root).expanduser()
    if not path.is_dir():
        raise DatasetFormatError(f"{path}: dataset root does not exist (expected {layout})")
    return path


def sequence_name(item: object) -> str:
    """A sequence name as the KITTI layout writes it: ``7`` -> ``"07"``, ``" 07"`` -> ``"07"`` (a YAML
    ``07`` arrives as the integer 7)."""
    return f"{item:02d}" if is_integer(item) else str(item).strip()


def split_names(value: str | int | Iterable[object] | None) -> list[str]:
    """Every name of a list, a comma-separated string or one integer, in order, as :func:`sequence_name`
    writes it, empties (``""``) and repeats kept: ``"00,,7"`` -> ``["00", "", "07"]``."""
    items: Iterable[object]
    if isinstance(value, str):
        items = value.split(",")
    elif isinstance(value, int):
        items = [value]
    else:
        items = value or []
    return [sequence_name(item) for item in items]


def sequence_names(value: str | int | Iterable[object] | None) -> list[str]:
    """Sequence names from a list, a comma-separated string or one integer, in order, without empties or
    repeats: ``"00, 07"``, ``[0, 7]`` -> ``["00", "07"]``."""
    return list(dict.fromkeys(name for name in split_names(value) if name))


def load_mapping(path: Path, what: str) -> dict[str, Any]:
    """The mapping in a YAML (or JSON) file, an OpenCV ``%YAML:1.0`` first line skipped (kept as an empty
    line, so that line numbers stay those of the file).

    Raises:
        DatasetFormatError: naming the file (and line) when it cannot be read, is not valid YAML or holds
            no mapping; ``what`` says what it should hold.
    """
    try:
        lines = path.read_text().splitlines()
    except OSError as e:
        raise DatasetFormatError(f"{path}: cannot read camera calibration ({e.strerror})") from None
    if lines and lines[0].startswith("%YAML:"):
        lines[0] = ""
    try:
        data = yaml.safe_load("\n".join(lines))
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(e, "problem", None) or type(e).__name__
        raise DatasetFormatError(f"{where(path, line)}: not valid YAML/JSON ({problem})") from None
    if not isinstance(data, dict):
        raise DatasetFormatError(f"{path}: expected a YAML mapping with {what}")
    return data


def check_choices(path: Path, data: dict[str, Any], choices: dict[str, str]) -> None:
    """DatasetFormatError naming ``path`` and the key where a calibration file gives another value than the
    one of ``choices`` (key -> the value this reader reads)."""
    for key, expected in choices.items():
        if key in data and data[key] != expected:
            raise DatasetFormatError(f"{path}: key '{key}': expected {expected!r}, got {data[key]!r}")


def yaml_array(
    path: Path, data: dict[str, Any], key: str, shape: tuple[int, ...], meaning: str
) -> np.ndarray:
    """``data[key]`` as a finite float64 array of ``shape`` (lists of numbers), or DatasetFormatError naming
    the file and key."""
    if key not in data:
        raise DatasetFormatError(f"{path}: key '{key}' missing (expected {meaning})")
    value = data[key]
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        array = np.zeros(0)
    numbers = all(is_number(v) for v in np.asarray(value, dtype=object).ravel())
    if array.shape != shape or not numbers or not np.all(np.isfinite(array)):
        raise DatasetFormatError(f"{path}: key '{key}': expected {meaning}, got {value!r}")
    return array


@dataclass(frozen=True)
class Sequence:
    """One sequence in lossvo's convention.

    Attributes:
        name: the sequence's name as the dataset names it (``"07"``, ``"rgbd_dataset_freiburg1_xyz"``,
            ``"V1_02_medium"``, ``"abandonedfactory/Easy/P000"``).
        images: (N,) frame paths in time order.
        times: (N,) float64 timestamps in seconds, strictly increasing.
        poses: (N, 4, 4) float64 T_w_c at the frames' timestamps, or None for a sequence without ground truth
            (usable for inference only).
        K: (3, 3) float64 intrinsics in pixels of the frames on disk.
        distortion: (D,) float64 OpenCV distortion coefficients (k1, k2, p1, p2[, k3]); all zeros when the
            frames are undistorted.
        size: (H, W) of the frames on disk, in pixels.
        dropped: frames the reader left out (for example outside the ground truth's time span).
    """

    name: str
    images: list[Path]
    times: np.ndarray
    poses: np.ndarray | None
    K: np.ndarray
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(5))
    size: tuple[int, int] = (0, 0)
    dropped: int = 0

    def __post_init__(self) -> None:
        n = len(self.images)
        if self.times.shape != (n,):
            raise UserError(f"sequence {self.name}: {self.times.shape} timestamps for {n} frames")
        if self.poses is not None and self.poses.shape != (n, 4, 4):
            raise UserError(f"sequence {self.name}: poses of shape {self.poses.shape} for {n} frames")
        if self.K.shape != (3, 3):
            raise UserError(f"sequence {self.name}: K of shape {self.K.shape}, expected (3, 3)")

    def every(self, n: int) -> Sequence:
        """The sequence with every ``n``-th frame kept (frames 0, n, 2n, ...): a lower frame rate."""
        if n == 1:
            return self
        poses = None if self.poses is None else self.poses[::n]
        return replace(self, images=self.images[::n], times=self.times[::n], poses=poses)

    @property
    def targets(self) -> np.ndarray:
        """(N - 1, 4, 4) float64 relative poses between consecutive frames, ``inv(T_k) @ T_{k+1}``."""
        if self.poses is None:
            raise DatasetFormatError(
                f"sequence {self.name} has no ground truth: it is usable for inference only"
            )
        return np.linalg.inv(self.poses[:-1]) @ self.poses[1:]


def unit_quaternions(path: Path, lines: list[int], q: np.ndarray, label: str, tolerance: float) -> np.ndarray:
    """(M, 4) quaternions divided by their norms.

    Args:
        path, lines: the file and the 1-based line of each quaternion; q: (M, 4) as read; label: how the
            file names them (``"(qx qy qz qw)"``, ``"q_RS"``); tolerance: the largest accepted |norm - 1|.
    Raises:
        DatasetFormatError: ``<path>:<line>: quaternion <label> of norm <n> (expected a unit quaternion,
            within <tolerance>)`` at the first one further from unit norm.
    """
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > tolerance)
    if bad.size:
        k = bad[0]
        raise DatasetFormatError(
            f"{where(path, lines[k])}: quaternion {label} of norm {norm[k]:.6g} "
            f"(expected a unit quaternion, within {tolerance})"
        )
    return q / norm[:, None]


def check_resolution(image: Path, size: tuple[int, int], calibration: Path) -> None:
    """DatasetFormatError unless the PNG ``image`` is ``size`` (H, W), the ``resolution`` its camera's
    ``calibration`` file states."""
    found = png_size(image)
    if found != size:
        raise DatasetFormatError(
            f"{image}: frame of {found[1]}x{found[0]} pixels, but {calibration} key 'resolution' says "
            f"{size[1]}x{size[0]}"
        )


def positive_resolution(path: Path, width: float, height: float, given: Any) -> tuple[int, int]:
    """(H, W) of a calibration file's ``resolution`` [width, height]; DatasetFormatError naming ``path``
    unless both are positive integers."""
    if width != int(width) or height != int(height) or width <= 0 or height <= 0:
        raise DatasetFormatError(
            f"{path}: key 'resolution': expected two positive integers [width, height], got {given!r}"
        )
    return int(height), int(width)


RIGID_TOLERANCE = 1e-4
"""Largest |RᵀR − I| entry and |det R − 1| accepted in a calibration's rigid transform (12 significant digits
in EuRoC's files)."""


def pose_matrices(t: np.ndarray, q_xyzw: np.ndarray) -> np.ndarray:
    """4x4 poses from translations and unit quaternions.

    Args:
        t: (M, 3) translations in metres; q_xyzw: (M, 4) unit quaternions (x, y, z, w).
    Returns:
        (M, 4, 4) float64 ``[[R(q), t], [0, 1]]``.
    """
    poses = np.zeros((len(t), 4, 4))
    poses[:, :3, :3] = Rotation.from_quat(q_xyzw).as_matrix()
    poses[:, :3, 3] = t
    poses[:, 3, 3] = 1.0
    return poses


def check_rigid(path: Path, T: np.ndarray, key: str) -> None:
    """DatasetFormatError naming ``path`` and ``key`` unless the (4, 4) ``T`` is a rigid transform: rotation
    block orthonormal with det +1 (within :data:`RIGID_TOLERANCE`), last row 0 0 0 1."""
    R = T[:3, :3]
    error = np.abs(R.T @ R - np.eye(3)).max()
    det = np.linalg.det(R)
    if error > RIGID_TOLERANCE or abs(det - 1.0) > RIGID_TOLERANCE:
        raise DatasetFormatError(
            f"{path}: key '{key}': rotation block is not a rotation (max |RᵀR − I| = {error:.2g}, "
            f"det = {det:.4g}; expected orthonormal, det +1)"
        )
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise DatasetFormatError(f"{path}: key '{key}': last row {T[3].tolist()} (expected 0 0 0 1)")


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_size(path: Path) -> tuple[int, int]:
    """(H, W) of a PNG file from its header, without decoding it.

    Raises:
        DatasetFormatError: naming the file if it cannot be read or is not a PNG.
    """
    try:
        with path.open("rb") as f:
            head = f.read(24)
    except OSError as e:
        raise DatasetFormatError(f"{path}: unreadable image ({e.strerror})") from None
    if len(head) < 24 or not head.startswith(_PNG_SIGNATURE) or head[12:16] != b"IHDR":
        raise DatasetFormatError(f"{path}: not a PNG file (expected a PNG frame)")
    width, height = struct.unpack(">II", head[16:24])
    return int(height), int(width)
