"""The data contract every dataset reader returns (:class:`Sequence`), sequence names, and the checks the
readers share: each raises one :class:`DatasetFormatError` line naming the file (and line or key) and what
was expected. The layouts and their conventions: docs/data.md.
"""

from __future__ import annotations

import os
import re
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
    """A file or folder that does not follow a dataset's layout."""


class UnknownCameraError(DatasetFormatError):
    """A sequence whose camera its layout does not give: ``data.sources.<name>.camera`` gives it."""


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
    """``fields`` of line ``line`` as floats; ``error`` ``<path>:<line>: expected <expected>, got '<field>'``
    at the first that is no number (``finite`` instead of ``expected`` at the first that is not finite)."""
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
    """The non-empty lines of a text file with their 1-based numbers, '#' comments left out where
    ``comments``; ``error`` ``<path>: cannot read <what> (<reason>)`` when the file cannot be read."""
    try:
        lines = path.read_text().splitlines()
    except OSError as e:
        raise error(f"{path}: cannot read {what} ({e.strerror})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: cannot read {what} (not a text file)") from None
    rows = [(i, line) for i, line in enumerate(lines, start=1) if line.strip()]
    return [(i, line) for i, line in rows if not (comments and line.lstrip().startswith("#"))]


def number_rows(
    path: Path, what: str, columns: int, expected: str, finite: str | None = None, comments: bool = True
) -> tuple[list[int], np.ndarray]:
    """The line numbers and (M, columns) float64 numbers of a text file's whitespace-separated lines; an
    error ``<path>:<line>: expected <expected>, got <n> fields`` at a line of another count."""
    rows = [(i, line.split()) for i, line in text_lines(path, what, comments)]
    values = []
    for i, fields in rows:
        if len(fields) != columns:
            raise DatasetFormatError(f"{where(path, i)}: expected {expected}, got {len(fields)} fields")
        values.append(finite_numbers(path, i, fields, expected, finite))
    return [i for i, _ in rows], np.array(values, dtype=np.float64).reshape(-1, columns)


def check_increasing(path: Path, lines: list[int], stamps: np.ndarray, unit: str = "") -> None:
    """An error at the first of ``lines`` whose stamp (of (M,) ``stamps``, in ``unit``) does not follow the
    previous line's."""
    bad = np.flatnonzero(np.diff(stamps) <= 0)
    if bad.size:
        k = bad[0] + 1
        raise DatasetFormatError(
            f"{where(path, lines[k])}: timestamp {stamps[k]}{unit} does not follow {stamps[k - 1]}{unit} on "
            f"line {lines[k - 1]} (expected strictly increasing timestamps)"
        )


def listed_frames(list_path: Path, folder: Path, names: list[str]) -> list[Path]:
    """``folder / name`` for each name of a frame list; an error at the list's line of the first missing."""
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
    """Whether a sequence's ground-truth file exists; an error naming it when missing and ``require``."""
    if require and not path.is_file():
        raise error(f"{path}: no {what} for sequence {name} (needed for training/evaluation)")
    return path.is_file()


def existing_root(root: str | os.PathLike, layout: str) -> Path:
    """``root`` (``~`` expanded); an error naming it and the expected ``layout`` when it is no folder."""
    path = Path(root).expanduser()
    if not path.is_dir():
        raise DatasetFormatError(f"{path}: dataset root does not exist (expected {layout})")
    return path


def find_sequences(root: str | os.PathLike, marker: str, *shapes: str) -> list[str]:
    """The sorted names (paths under ``root``) of the folders of a shape (``"<env>/auv0/<track>"``: each
    ``<...>`` any name) that hold ``marker`` (a file or folder path); an error when ``root`` is no folder."""
    base = existing_root(root, f"ROOT/{shapes[0]}/{marker}")
    globs = [re.sub(r"<[^>]*>", "*", shape) for shape in shapes]
    return sorted(
        {p.relative_to(base).as_posix() for g in globs for p in base.glob(g) if (p / marker).exists()}
    )


def sequence_folder(root: str | os.PathLike, name: str, marker: str, *shapes: str) -> Path:
    """``root/name``, checked to hold ``marker``; an error naming the sequences found otherwise."""
    path = existing_root(root, f"ROOT/{shapes[0]}/{marker}") / name
    if not (path / marker).exists():
        found = ", ".join(find_sequences(root, marker, *shapes)) or "none"
        raise DatasetFormatError(
            f"{path / marker}: sequence {name!r} not found "
            f"(expected ROOT/{shapes[0]}/{marker}; found: {found})"
        )
    return path


def sequence_name(item: object) -> str:
    """A sequence name as the KITTI layout writes it: ``7`` -> ``"07"`` (a YAML ``07`` arrives as 7),
    ``" 07"`` -> ``"07"``."""
    return f"{item:02d}" if is_integer(item) else str(item).strip()


def split_names(value: str | int | Iterable[object] | None) -> list[str]:
    """Every name of a list, a comma-separated string or one integer, as :func:`sequence_name` writes it,
    empties and repeats kept: ``"00,,7"`` -> ``["00", "", "07"]``."""
    items: Iterable[object]
    if isinstance(value, str):
        items = value.split(",")
    elif isinstance(value, int):
        items = [value]
    else:
        items = value or []
    return [sequence_name(item) for item in items]


def sequence_names(value: str | int | Iterable[object] | None) -> list[str]:
    """:func:`split_names` without empties or repeats: ``"00, 07"``, ``[0, 7]`` -> ``["00", "07"]``."""
    return list(dict.fromkeys(name for name in split_names(value) if name))


def load_mapping(path: Path, what: str, choices: dict[str, str]) -> dict[str, Any]:
    """The mapping in a YAML (or JSON) file holding ``what``, an error naming a key of ``choices`` (the
    values read) that holds another value; an OpenCV ``%YAML:1.0`` first line is skipped (PyYAML rejects
    it), line numbers kept."""
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
    for key, expected in choices.items():
        if key in data and data[key] != expected:
            raise DatasetFormatError(f"{path}: key '{key}': expected {expected!r}, got {data[key]!r}")
    return data


def yaml_array(
    path: Path, data: dict[str, Any], key: str, shape: tuple[int, ...], meaning: str
) -> np.ndarray:
    """``data[key]`` as a finite float64 array of ``shape``; an error naming the file and key otherwise."""
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


def yaml_resolution(path: Path, data: dict[str, Any]) -> tuple[int, int]:
    """(H, W) of a calibration file's ``resolution: [width, height]``, both positive integers."""
    width, height = yaml_array(path, data, "resolution", (2,), "[width, height] in pixels")
    if width != int(width) or height != int(height) or width <= 0 or height <= 0:
        raise DatasetFormatError(
            f"{path}: key 'resolution': expected two positive integers [width, height], "
            f"got {data['resolution']!r}"
        )
    return int(height), int(width)


@dataclass(frozen=True)
class Sequence:
    """One sequence in lossvo's convention (float64 T_w_c, camera x right, y down, z forward; seconds).

    Attributes:
        name: the sequence's name as the dataset names it (``"07"``, ``"V1_02_medium"``).
        images: (N,) frame paths in time order; times: (N,) seconds, strictly increasing.
        poses: (N, 4, 4) T_w_c at the frames' times, or None without ground truth (inference only).
        K: (3, 3) intrinsics in pixels of the frames on disk; distortion: (D,) OpenCV coefficients (k1, k2,
            p1, p2[, k3]), zeros for undistorted frames; size: (H, W) of the frames on disk.
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


def quaternion_poses(
    path: Path, lines: list[int], t: np.ndarray, q_xyzw: np.ndarray, label: str, tolerance: float
) -> np.ndarray:
    """(M, 4, 4) ``[[R(q), t], [0, 1]]`` from translations (M, 3) and quaternions (M, 4) x y z w, each
    normalised; an error at the first line (of ``lines``) whose quaternion's norm is further than
    ``tolerance`` from 1 (``label``: how the file names it)."""
    norm = np.linalg.norm(q_xyzw, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > tolerance)
    if bad.size:
        k = bad[0]
        raise DatasetFormatError(
            f"{where(path, lines[k])}: quaternion {label} of norm {norm[k]:.6g} "
            f"(expected a unit quaternion, within {tolerance})"
        )
    poses = np.zeros((len(t), 4, 4))
    poses[:, :3, :3] = Rotation.from_quat(q_xyzw / norm[:, None]).as_matrix()
    poses[:, :3, 3] = t
    poses[:, 3, 3] = 1.0
    return poses


RIGID_TOLERANCE = 1e-4
"""Largest |RᵀR − I| entry accepted in a calibration's rigid transform (EuRoC's have 12 digits)."""


def check_rotations(
    places: list[str], R: np.ndarray, tolerance: float, error: type[DatasetFormatError] = DatasetFormatError
) -> None:
    """An error at the place (of ``places``) of the first of R (M, 3, 3) that is no rotation: an entry of
    RᵀR − I over ``tolerance``, or det < 0."""
    deviation = np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((deviation > tolerance) | (det < 0))
    if bad.size:
        k = bad[0]
        raise error(
            f"{places[k]}: rotation block is not a rotation (max |RᵀR − I| = {deviation[k]:.2g}, "
            f"det = {det[k]:.4g}; expected orthonormal, det +1)"
        )


def check_rigid(path: Path, T: np.ndarray, key: str) -> None:
    """An error naming the file and key unless the (4, 4) ``T`` is a rigid transform."""
    check_rotations([f"{path}: key '{key}'"], T[None, :3, :3], RIGID_TOLERANCE)
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise DatasetFormatError(f"{path}: key '{key}': last row {T[3].tolist()} (expected 0 0 0 1)")


def png_size(path: Path) -> tuple[int, int]:
    """(H, W) of a PNG file from its header, without decoding it."""
    try:
        with path.open("rb") as f:
            head = f.read(24)
    except OSError as e:
        raise DatasetFormatError(f"{path}: unreadable image ({e.strerror})") from None
    if len(head) < 24 or not head.startswith(b"\x89PNG\r\n\x1a\n") or head[12:16] != b"IHDR":
        raise DatasetFormatError(f"{path}: not a PNG file (expected a PNG frame)")
    width, height = struct.unpack(">II", head[16:24])
    return int(height), int(width)
