"""The TartanAir reader: NED poses in lossvo's camera convention, times from the rate, the fixed camera, and
one DatasetFormatError line for every bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lossvo.console import UserError
from lossvo.data import tartanair
from lossvo.data.sequence import DatasetFormatError

NAME = "abandonedfactory/Easy/P000"

P = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""tartanair_tools' ``ned2cam`` T: camera x = NED y (right), y = NED z (down), z = NED x (forward)."""


def pose(R: np.ndarray | None = None, t: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = t
    return T


def Ry(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def Rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose_lines(ned_poses: np.ndarray) -> str:
    """``tx ty tz qx qy qz qw`` lines of (N, 4, 4) NED poses."""
    q = Rotation.from_matrix(ned_poses[:, :3, :3]).as_quat()
    rows = np.concatenate([ned_poses[:, :3, 3], q], axis=1)
    return "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in rows)


def write_frames(folder: Path, count: int, size: tuple[int, int] = (480, 640)) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    first = folder / "000000_left.png"
    cv2.imwrite(str(first), np.zeros((*size, 3), np.uint8))
    for k in range(1, count):
        shutil.copyfile(first, folder / f"{k:06d}_left.png")


def write_sequence(root: Path, ned_poses: np.ndarray, name: str = NAME) -> Path:
    folder = root / name
    write_frames(folder / "image_left", len(ned_poses))
    (folder / "pose_left.txt").write_text(pose_lines(ned_poses))
    return folder


def relative(poses: np.ndarray) -> np.ndarray:
    return np.linalg.inv(poses[:-1]) @ poses[1:]


# --------------------------------------------------------------------------------------------------
# The NED -> camera convention
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("start_yaw", [0.0, 0.7])
@pytest.mark.parametrize(
    ("ned_step", "camera_step"),
    [
        ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0)),
        ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    ],
    ids=["forward", "right", "down"],
)
def test_a_step_along_the_body_axes_is_a_step_along_the_camera_axes(
    tmp_path: Path,
    ned_step: tuple[float, float, float],
    camera_step: tuple[float, float, float],
    start_yaw: float,
) -> None:
    R0 = Rz(start_yaw)
    start = pose(R0, (5.0, -2.0, 1.0))
    end = pose(R0, tuple(start[:3, 3] + R0 @ np.array(ned_step)))
    write_sequence(tmp_path, np.stack([start, end]))
    seq = tartanair.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    step = relative(seq.poses)[0]
    np.testing.assert_allclose(step[:3, 3], camera_step, atol=1e-12)
    np.testing.assert_allclose(step[:3, :3], np.eye(3), atol=1e-12)


def test_a_yaw_to_the_right_is_a_positive_rotation_about_the_camera_y(tmp_path: Path) -> None:
    theta = 0.3
    write_sequence(tmp_path, np.stack([pose(), pose(Rz(theta))]))
    seq = tartanair.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    R = relative(seq.poses)[0][:3, :3]
    np.testing.assert_allclose(R, Ry(theta), atol=1e-12)
    np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], [np.sin(theta), 0.0, np.cos(theta)], atol=1e-12)


def test_the_world_axes_are_converted_like_the_body_axes(tmp_path: Path) -> None:
    write_sequence(tmp_path, np.stack([pose(), pose(t=(1.0, 2.0, 3.0))]))
    seq = tartanair.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    np.testing.assert_allclose(seq.poses[0], np.eye(4), atol=1e-15)
    np.testing.assert_allclose(seq.poses[1][:3, 3], [2.0, 3.0, 1.0])


def test_a_constructed_trajectory_round_trips(tmp_path: Path) -> None:
    n = 20
    rng = np.random.default_rng(0)
    T_cam = np.tile(np.eye(4), (n, 1, 1))
    T_cam[:, :3, :3] = Rotation.random(n, random_state=1).as_matrix()
    T_cam[:, :3, 3] = rng.normal(scale=10.0, size=(n, 3))
    P4 = np.eye(4)
    P4[:3, :3] = P
    write_sequence(tmp_path, P4.T @ T_cam @ P4)
    seq = tartanair.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    np.testing.assert_allclose(seq.poses, T_cam, atol=1e-12)
    steps = relative(seq.poses)
    np.testing.assert_allclose(np.linalg.det(steps[:, :3, :3]), 1.0, atol=1e-12)
    np.testing.assert_allclose(
        steps[:, :3, :3].transpose(0, 2, 1) @ steps[:, :3, :3], np.tile(np.eye(3), (n - 1, 1, 1)), atol=1e-12
    )


def test_ned_to_camera_is_vectorised_over_leading_axes() -> None:
    T = np.tile(pose(Rz(0.2), (1.0, 2.0, 3.0)), (2, 3, 1, 1))
    out = tartanair.ned_to_camera(T)
    assert out.shape == (2, 3, 4, 4)
    np.testing.assert_allclose(out[1, 2, :3, 3], [2.0, 3.0, 1.0])
    np.testing.assert_allclose(out[0, 0, :3, :3], Ry(0.2), atol=1e-15)


# --------------------------------------------------------------------------------------------------
# Sequences
# --------------------------------------------------------------------------------------------------


def test_times_come_from_the_rate_and_the_camera_is_tartanairs(tmp_path: Path) -> None:
    write_sequence(tmp_path, np.stack([pose()] * 4))
    seq = tartanair.load_sequence(tmp_path, NAME)
    np.testing.assert_allclose(seq.times, [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(
        tartanair.load_sequence(tmp_path, NAME, rate_hz=25.0).times, np.arange(4) / 25.0
    )
    np.testing.assert_array_equal(seq.K, [[320.0, 0.0, 320.0], [0.0, 320.0, 240.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(seq.distortion, np.zeros(5))
    assert seq.size == (480, 640)
    assert [p.name for p in seq.images] == [f"{k:06d}_left.png" for k in range(4)]
    assert seq.name == NAME and seq.dropped == 0


def test_list_sequences_names_env_level_trajectory(tmp_path: Path) -> None:
    for name in ("seasonsforest/Hard/P001", NAME, "abandonedfactory/Hard/P000"):
        write_frames(tmp_path / name / "image_left", 1)
    (tmp_path / "notes").mkdir()
    assert tartanair.list_sequences(tmp_path) == [
        "abandonedfactory/Easy/P000",
        "abandonedfactory/Hard/P000",
        "seasonsforest/Hard/P001",
    ]


def test_without_a_pose_file_the_sequence_is_for_inference_only(tmp_path: Path) -> None:
    write_frames(tmp_path / NAME / "image_left", 3)
    seq = tartanair.load_sequence(tmp_path, NAME, require_poses=False)
    assert seq.poses is None and len(seq.images) == 3
    with pytest.raises(DatasetFormatError, match=r"pose_left\.txt: no pose file for sequence"):
        tartanair.load_sequence(tmp_path, NAME)


# --------------------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------------------


def assert_one_line(error: pytest.ExceptionInfo[DatasetFormatError]) -> None:
    assert "\n" not in str(error.value)


def test_a_missing_root(tmp_path: Path) -> None:
    with pytest.raises(DatasetFormatError, match="dataset root does not exist") as error:
        tartanair.load_sequence(tmp_path / "nowhere", NAME)
    assert_one_line(error)


def test_an_unknown_sequence_lists_the_names_found(tmp_path: Path) -> None:
    write_sequence(tmp_path, np.stack([pose()] * 2))
    with pytest.raises(
        DatasetFormatError,
        match=r"'abandonedfactory/Easy/P009' not found .*found: abandonedfactory/Easy/P000\)",
    ) as error:
        tartanair.load_sequence(tmp_path, "abandonedfactory/Easy/P009")
    assert_one_line(error)


def test_no_frames(tmp_path: Path) -> None:
    (tmp_path / NAME / "image_left").mkdir(parents=True)
    with pytest.raises(DatasetFormatError, match=r"image_left: expected frames 000000_left\.png.*found none"):
        tartanair.load_sequence(tmp_path, NAME)


def test_a_gap_in_the_frame_numbers(tmp_path: Path) -> None:
    write_sequence(tmp_path, np.stack([pose()] * 3))
    (tmp_path / NAME / "image_left" / "000001_left.png").unlink()
    with pytest.raises(
        DatasetFormatError, match=r"000001_left\.png: frame missing .*found 000002_left\.png next"
    ):
        tartanair.load_sequence(tmp_path, NAME)


def test_frames_of_another_size_get_K_scaled(tmp_path: Path) -> None:
    """A 160x120 copy of the 640x480 frames: K scaled by 1/4 as cv2.resize maps pixel centres."""
    write_frames(tmp_path / NAME / "image_left", 2, size=(120, 160))
    (tmp_path / NAME / "pose_left.txt").write_text(pose_lines(np.stack([pose()] * 2)))
    seq = tartanair.load_sequence(tmp_path, NAME)
    assert seq.size == (120, 160)
    np.testing.assert_allclose(seq.K, [[80.0, 0.0, 79.625], [0.0, 80.0, 59.625], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("0 0 0 0 0 0", r"pose_left\.txt:2: expected 7 numbers 'tx ty tz qx qy qz qw', got 6 fields"),
        ("0 0 0 0 0 0 1 0", r"pose_left\.txt:2: expected 7 numbers .* got 8 fields"),
        ("0 0 zero 0 0 0 1", r"pose_left\.txt:2: expected 7 numbers .* got 'zero'"),
        ("0 0 nan 0 0 0 1", r"pose_left\.txt:2: expected finite numbers, got 'nan'"),
        ("0 0 0 0 0 0 2", r"pose_left\.txt:2: quaternion \(qx qy qz qw\) of norm 2 "),
    ],
    ids=["too-few", "too-many", "word", "nan", "not-unit"],
)
def test_a_bad_pose_line_names_file_and_line(tmp_path: Path, line: str, message: str) -> None:
    folder = write_sequence(tmp_path, np.stack([pose()] * 3))
    lines = (folder / "pose_left.txt").read_text().splitlines()
    lines[1] = line
    (folder / "pose_left.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetFormatError, match=message) as error:
        tartanair.load_sequence(tmp_path, NAME)
    assert_one_line(error)


def test_an_empty_pose_file(tmp_path: Path) -> None:
    folder = write_sequence(tmp_path, np.stack([pose()] * 2))
    (folder / "pose_left.txt").write_text("\n")
    with pytest.raises(DatasetFormatError, match=r"pose_left\.txt: empty pose file"):
        tartanair.load_sequence(tmp_path, NAME)


def test_pose_count_differs_from_frame_count(tmp_path: Path) -> None:
    folder = write_sequence(tmp_path, np.stack([pose()] * 3))
    (folder / "pose_left.txt").write_text(pose_lines(np.stack([pose()] * 2)))
    with pytest.raises(
        DatasetFormatError, match=r"pose_left\.txt: 2 poses but 3 frames in .*image_left"
    ) as error:
        tartanair.load_sequence(tmp_path, NAME)
    assert_one_line(error)


def test_a_rate_that_is_not_positive(tmp_path: Path) -> None:
    write_sequence(tmp_path, np.stack([pose()] * 2))
    with pytest.raises(UserError, match="rate_hz must be positive"):
        tartanair.load_sequence(tmp_path, NAME, rate_hz=0.0)
