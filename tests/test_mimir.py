"""The MIMIR-UW reader: camera poses T_w_b @ T_BS in lossvo's convention, interpolation at the frames' times,
a real EuRoC-format ground truth, and one DatasetFormatError line for every bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evo_data import EUROC_V102, evo_file
from lossvo.data import mimir
from lossvo.data.sequence import DatasetFormatError

NAME = "SeaFloor/auv0/track0"
T0_NS = 1661868173547958016
"""A stamp from the authors' ORB-SLAM3 MIMIR_TimeStamps/SeaFloor_track0.txt (nanoseconds)."""

P4 = np.eye(4)
P4[:3, :3] = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]
"""NED (x forward, y right, z down) -> lossvo (x right, y down, z forward), body and world alike."""

README_T_BS = np.array(
    [
        [0.9659258262890682, -0.0, -0.25881904510252074, 0.45],
        [0.0, 1.0, -0.0, -0.06],
        [0.25881904510252074, 0.0, 0.9659258262890682, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""The README's example front_left camera: pitched 15 degrees down, 0.45 m forward, 0.06 m left."""

SIZE = (8, 12)


def pose(
    R: np.ndarray | None = None, t: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0)
) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = t
    return T


def Rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def Ry(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def sensor(
    T_BS: np.ndarray = README_T_BS, size: tuple[int, int] = SIZE, **changes: object
) -> dict[str, object]:
    """A sensor.yaml as the README shows it."""
    data: dict[str, object] = {
        "sensor_type": "front_left",
        "comment": "rgb",
        "T_BS": T_BS.tolist(),
        "rate_hz": 30,
        "resolution": [size[1], size[0]],
        "camera_model": "pinhole",
        "intrinsics": [[6.0, 0.0, 6.0], [0.0, 6.0, 4.0], [0.0, 0.0, 1.0]],
        "distortion_model": "radial-tangential",
        "distortion_coefficients": [0.1, -0.2, 0.001, 0.002, 0.05],
    }
    data.update(changes)
    return data


def groundtruth_text(
    ns: list[int], T_w_b: np.ndarray, header: str = "#timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z"
) -> str:
    q = Rotation.from_matrix(T_w_b[:, :3, :3]).as_quat()[:, [3, 0, 1, 2]]
    lines = [header] if header else []
    for stamp, t, qq in zip(ns, T_w_b[:, :3, 3], q, strict=True):
        lines.append(",".join([str(stamp), *(repr(float(v)) for v in (*t, *qq))]))
    return "\n".join(lines) + "\n"


def write_track(
    root: Path,
    camera_ns: list[int],
    gt_ns: list[int] | None = None,
    T_w_b: np.ndarray | None = None,
    T_BS: np.ndarray = README_T_BS,
    name: str = NAME,
) -> Path:
    """A MIMIR track: frames at ``camera_ns`` and (unless ``T_w_b`` is None) the ground truth at ``gt_ns``."""
    folder = root / name
    cam = folder / "rgb" / "cam0"
    (cam / "data").mkdir(parents=True)
    first = cam / "data" / f"{camera_ns[0]}.png"
    cv2.imwrite(str(first), np.zeros((*SIZE, 3), np.uint8))
    for stamp in camera_ns[1:]:
        shutil.copyfile(first, cam / "data" / f"{stamp}.png")
    (cam / "data.csv").write_text("#timestamp [ns],filename\n" + "".join(f"{s},{s}.png\n" for s in camera_ns))
    (cam / "sensor.yaml").write_text(json.dumps(sensor(T_BS), indent=4))
    if T_w_b is not None:
        (folder / "pose_groundtruth").mkdir()
        stamps = camera_ns if gt_ns is None else gt_ns
        (folder / "pose_groundtruth" / "data.csv").write_text(groundtruth_text(stamps, T_w_b))
    return folder


def relative(poses: np.ndarray) -> np.ndarray:
    return np.linalg.inv(poses[:-1]) @ poses[1:]


def stamps(count: int, step_ns: int = 40_000_000) -> list[int]:
    return [T0_NS + k * step_ns for k in range(count)]


# --------------------------------------------------------------------------------------------------
# Conventions
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("ned_step", "camera_step"),
    [
        ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0)),
        ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    ],
    ids=["forward", "right", "down"],
)
def test_with_an_identity_T_BS_body_steps_are_camera_steps(
    tmp_path: Path, ned_step: tuple[float, float, float], camera_step: tuple[float, float, float]
) -> None:
    R0 = Rz(1.1)
    start = pose(R0, (3.0, 4.0, 5.0))
    end = pose(R0, start[:3, 3] + R0 @ np.array(ned_step))
    write_track(tmp_path, stamps(2), T_w_b=np.stack([start, end]), T_BS=np.eye(4))
    seq = mimir.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    step = relative(seq.poses)[0]
    np.testing.assert_allclose(step[:3, 3], camera_step, atol=1e-12)
    np.testing.assert_allclose(step[:3, :3], np.eye(3), atol=1e-12)


def test_a_yaw_to_the_right_is_a_positive_rotation_about_the_camera_y(tmp_path: Path) -> None:
    write_track(tmp_path, stamps(2), T_w_b=np.stack([pose(), pose(Rz(0.25))]), T_BS=np.eye(4))
    seq = mimir.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    np.testing.assert_allclose(relative(seq.poses)[0][:3, :3], Ry(0.25), atol=1e-12)


def test_the_camera_pose_applies_T_BS_of_a_camera_pitched_down(tmp_path: Path) -> None:
    write_track(tmp_path, stamps(2), T_w_b=np.stack([pose(), pose(t=(1.0, 0.0, 0.0))]))
    seq = mimir.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    pitch = np.radians(15.0)
    # The camera sits 0.45 m ahead and 0.06 m left of the body; lossvo's world is x right, y down, z forward.
    np.testing.assert_allclose(seq.poses[0][:3, 3], [-0.06, 0.0, 0.45], atol=1e-12)
    # Its optical axis points forward and 15 degrees down.
    np.testing.assert_allclose(seq.poses[0][:3, 2], [0.0, np.sin(pitch), np.cos(pitch)], atol=1e-12)
    # A body step 1 m forward moves the down-pitched camera along its optical axis and towards its image top.
    np.testing.assert_allclose(
        relative(seq.poses)[0][:3, 3], [0.0, -np.sin(pitch), np.cos(pitch)], atol=1e-12
    )


def test_frames_between_ground_truth_rows_are_interpolated_and_outside_ones_dropped(tmp_path: Path) -> None:
    gt_ns = [T0_NS + k * 100_000_000 for k in range(4)]
    gt_s = np.arange(4) * 0.1
    speed, yaw_rate = 2.0, 1.5
    T_w_b = np.stack([pose(Rz(yaw_rate * t), (speed * t, 0.0, 0.0)) for t in gt_s])
    offsets_ms = [-10, 50, 100, 150, 275, 310]
    camera_ns = [T0_NS + ms * 1_000_000 for ms in offsets_ms]
    write_track(tmp_path, camera_ns, gt_ns, T_w_b, T_BS=np.eye(4))
    seq = mimir.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    assert seq.dropped == 2
    assert [p.name for p in seq.images] == [f"{s}.png" for s in camera_ns[1:5]]
    t = np.array([0.05, 0.1, 0.15, 0.275])
    np.testing.assert_allclose(seq.times - seq.times[0], t - t[0], atol=1e-6)  # float64 s near 1.7e9: 2.4e-7
    np.testing.assert_allclose(seq.poses[:, :3, 3], np.stack([[0.0, 0.0, speed * s] for s in t]), atol=1e-12)
    np.testing.assert_allclose(seq.poses[:, :3, :3], np.stack([Ry(yaw_rate * s) for s in t]), atol=1e-12)


def test_the_real_euroc_format_ground_truth_is_read_column_by_column(tmp_path: Path) -> None:
    """EuRoC V1_02's ground truth (17 columns; the study's loader reads the first 8 alike) as MIMIR's."""
    source = evo_file(EUROC_V102)
    with source.open() as f:
        rows = [line.strip().split(",") for line in f if line.strip() and not line.startswith("#")][:400]
    gt_ns = [int(r[0]) for r in rows]
    exact = gt_ns[:400:10]
    between = [(gt_ns[k] + gt_ns[k + 1]) // 2 for k in (5, 123, 301)]
    camera_ns = sorted(exact + between)
    folder = write_track(tmp_path, camera_ns, T_w_b=None, T_BS=np.eye(4))
    (folder / "pose_groundtruth").mkdir()
    shutil.copyfile(source, folder / "pose_groundtruth" / "data.csv")
    seq = mimir.load_sequence(tmp_path, NAME)
    assert seq.poses is not None and seq.dropped == 0
    values = np.array([[float(v) for v in r[1:8]] for r in rows])
    T_w_b = np.tile(np.eye(4), (len(rows), 1, 1))
    T_w_b[:, :3, :3] = Rotation.from_quat(values[:, [4, 5, 6, 3]]).as_matrix()
    T_w_b[:, :3, 3] = values[:, :3]
    expected = P4 @ T_w_b @ P4.T
    at = {stamp: k for k, stamp in enumerate(camera_ns)}
    np.testing.assert_allclose(seq.poses[[at[s] for s in exact]], expected[:400:10], atol=1e-9)
    for k, stamp in zip((5, 123, 301), between, strict=True):
        midpoint = (expected[k, :3, 3] + expected[k + 1, :3, 3]) / 2
        np.testing.assert_allclose(seq.poses[at[stamp], :3, 3], midpoint, atol=1e-6)
    assert seq.times[0] == pytest.approx(gt_ns[0] * 1e-9, abs=1e-6)


def test_the_camera_comes_from_sensor_yaml(tmp_path: Path) -> None:
    write_track(tmp_path, stamps(2), T_w_b=np.stack([pose(), pose()]))
    seq = mimir.load_sequence(tmp_path, NAME)
    np.testing.assert_array_equal(seq.K, [[6.0, 0.0, 6.0], [0.0, 6.0, 4.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(seq.distortion, [0.1, -0.2, 0.001, 0.002, 0.05])
    assert seq.size == SIZE
    np.testing.assert_allclose(np.diff(seq.times), 0.04, atol=1e-6)


def test_four_distortion_coefficients_are_padded(tmp_path: Path) -> None:
    folder = write_track(tmp_path, stamps(2), T_w_b=np.stack([pose(), pose()]))
    yaml_path = folder / "rgb" / "cam0" / "sensor.yaml"
    yaml_path.write_text(json.dumps(sensor(distortion_coefficients=[0.1, -0.2, 0.001, 0.002])))
    np.testing.assert_array_equal(
        mimir.load_sequence(tmp_path, NAME).distortion, [0.1, -0.2, 0.001, 0.002, 0.0]
    )


def test_a_header_without_hash_is_skipped(tmp_path: Path) -> None:
    folder = write_track(
        tmp_path, stamps(2), T_w_b=np.stack([pose(), pose(t=(1.0, 0.0, 0.0))]), T_BS=np.eye(4)
    )
    gt = folder / "pose_groundtruth" / "data.csv"
    gt.write_text(
        groundtruth_text(
            stamps(2), np.stack([pose(), pose(t=(1.0, 0.0, 0.0))]), header="timestamp,x,y,z,qw,qx,qy,qz"
        )
    )
    seq = mimir.load_sequence(tmp_path, NAME)
    assert seq.poses is not None
    np.testing.assert_allclose(seq.poses[1][:3, 3], [0.0, 0.0, 1.0])


def test_list_sequences_finds_both_orders_of_track_and_auv0(tmp_path: Path) -> None:
    write_track(tmp_path, stamps(1), name="SeaFloor/auv0/track1")
    write_track(tmp_path, stamps(1), name="OceanFloor/track0_light/auv0")
    write_track(tmp_path, stamps(1), name=NAME)
    (tmp_path / "SandPipe" / "auv0" / "track0" / "imu0").mkdir(parents=True)
    assert mimir.list_sequences(tmp_path) == ["OceanFloor/track0_light/auv0", NAME, "SeaFloor/auv0/track1"]
    assert len(mimir.load_sequence(tmp_path, "OceanFloor/track0_light/auv0", require_poses=False).images) == 1


def test_without_ground_truth_the_sequence_is_for_inference_only(tmp_path: Path) -> None:
    write_track(tmp_path, stamps(3))
    seq = mimir.load_sequence(tmp_path, NAME, require_poses=False)
    assert seq.poses is None and len(seq.images) == 3 and seq.dropped == 0
    with pytest.raises(DatasetFormatError, match=r"pose_groundtruth/data\.csv: no ground truth for sequence"):
        mimir.load_sequence(tmp_path, NAME)


# --------------------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------------------


def load_error(root: Path, message: str, name: str = NAME) -> None:
    with pytest.raises(DatasetFormatError, match=message) as error:
        mimir.load_sequence(root, name)
    assert "\n" not in str(error.value)


@pytest.fixture
def track(tmp_path: Path) -> Path:
    """A valid three-frame track (T_BS identity), its folder."""
    return write_track(tmp_path, stamps(3), T_w_b=np.stack([pose(), pose(), pose()]), T_BS=np.eye(4))


def test_a_missing_root(tmp_path: Path) -> None:
    load_error(tmp_path / "nowhere", "dataset root does not exist")


def test_an_unknown_sequence_lists_the_names_found(tmp_path: Path, track: Path) -> None:
    load_error(
        tmp_path,
        r"'SeaFloor/auv0/track7' not found .*found: SeaFloor/auv0/track0\)",
        name="SeaFloor/auv0/track7",
    )


def test_a_missing_frame_list(tmp_path: Path, track: Path) -> None:
    (track / "rgb" / "cam0" / "data.csv").unlink()
    load_error(tmp_path, r"cam0/data\.csv: cannot read camera list")


def test_a_frame_list_going_backwards(tmp_path: Path, track: Path) -> None:
    s = stamps(3)
    (track / "rgb" / "cam0" / "data.csv").write_text(
        f"#timestamp [ns],filename\n{s[0]},{s[0]}.png\n{s[2]},{s[2]}.png\n{s[1]},{s[1]}.png\n"
    )
    load_error(tmp_path, r"cam0/data\.csv:4: timestamp .* does not follow .*strictly increasing")


def test_a_listed_frame_that_does_not_exist(tmp_path: Path, track: Path) -> None:
    (track / "rgb" / "cam0" / "data" / f"{stamps(3)[1]}.png").unlink()
    load_error(tmp_path, rf"cam0/data\.csv:3: frame .*{stamps(3)[1]}\.png does not exist")


def test_a_missing_sensor_yaml(tmp_path: Path, track: Path) -> None:
    (track / "rgb" / "cam0" / "sensor.yaml").unlink()
    load_error(tmp_path, r"sensor\.yaml: cannot read camera calibration")


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"intrinsics": None}, r"sensor\.yaml: key 'intrinsics' missing \(expected a 3x3 list"),
        ({"intrinsics": [6.0, 6.0, 6.0, 4.0]}, r"sensor\.yaml: key 'intrinsics': expected a 3x3 list"),
        (
            {"intrinsics": [[6.0, 0.0, 6.0], [0.0, -6.0, 4.0], [0.0, 0.0, 1.0]]},
            r"sensor\.yaml: key 'intrinsics': expected .* fx, fy > 0",
        ),
        ({"resolution": [12]}, r"sensor\.yaml: key 'resolution': expected \[width, height\]"),
        ({"resolution": [16, 8]}, r"frame of 12x8 pixels, but .*sensor\.yaml key 'resolution' says 16x8"),
        (
            {"distortion_coefficients": [0.0, 0.0]},
            r"sensor\.yaml: key 'distortion_coefficients': expected \[k1, k2, p1, p2, k3\]",
        ),
        (
            {"camera_model": "fisheye"},
            r"sensor\.yaml: key 'camera_model': expected 'pinhole', got 'fisheye'",
        ),
        ({"T_BS": np.eye(3).tolist()}, r"sensor\.yaml: key 'T_BS': expected a 4x4 list"),
        ({"T_BS": (2 * np.eye(4)).tolist()}, r"sensor\.yaml: key 'T_BS': rotation block is not a rotation"),
        (
            {"T_BS": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]},
            r"sensor\.yaml: key 'T_BS': last row",
        ),
    ],
    ids=[
        "no-K",
        "flat-K",
        "negative-f",
        "short-resolution",
        "other-resolution",
        "two-coefficients",
        "fisheye",
        "3x3-T_BS",
        "scaled-T_BS",
        "last-row",
    ],
)
def test_a_bad_sensor_yaml_names_the_key(
    tmp_path: Path, track: Path, changes: dict[str, object], message: str
) -> None:
    data = sensor(np.eye(4))
    data.update(changes)
    data = {k: v for k, v in data.items() if v is not None}
    (track / "rgb" / "cam0" / "sensor.yaml").write_text(json.dumps(data))
    load_error(tmp_path, message)


def test_sensor_yaml_that_is_not_yaml(tmp_path: Path, track: Path) -> None:
    (track / "rgb" / "cam0" / "sensor.yaml").write_text('{\n  "T_BS": [1, 2,\n  : }\n')
    load_error(tmp_path, r"sensor\.yaml(:\d+)?: not valid YAML/JSON")


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("{s},0,0,0,1,0,0", r"data\.csv:3: expected 8 comma-separated columns like line 2, got 7"),
        ("{s},0,0,0,1,0,0,0,9", r"data\.csv:3: expected 8 comma-separated columns like line 2, got 9"),
        ("{s},0,0,zero,1,0,0,0", r"data\.csv:3: expected a number, got 'zero'"),
        ("{s},0,0,inf,1,0,0,0", r"data\.csv:3: expected a finite number, got 'inf'"),
        ("{s}.5,0,0,0,1,0,0,0", r"data\.csv:3: expected a timestamp in integer nanoseconds, got '\d+\.5'"),
        ("{s},0,0,0,2,0,0,0", r"data\.csv:3: quaternion \(qw qx qy qz\) of norm 2 "),
        (
            "{first},0,0,0,1,0,0,0",
            r"data\.csv:3: timestamp \d+ ns does not follow \d+ ns on line 2 \(expected strictly",
        ),
        ("{before},0,0,0,1,0,0,0", r"data\.csv:3: timestamp \d+ ns does not follow"),
    ],
    ids=["too-few", "too-many", "word", "inf", "fraction", "not-unit", "repeated", "backwards"],
)
def test_a_bad_ground_truth_line_names_file_and_line(
    tmp_path: Path, track: Path, line: str, message: str
) -> None:
    gt = track / "pose_groundtruth" / "data.csv"
    lines = gt.read_text().splitlines()
    s = stamps(3)
    lines[2] = line.format(s=s[1], first=s[0], before=s[0] - 1)
    gt.write_text("\n".join(lines) + "\n")
    load_error(tmp_path, message)


def test_a_ground_truth_with_fewer_than_8_columns(tmp_path: Path, track: Path) -> None:
    (track / "pose_groundtruth" / "data.csv").write_text(f"{stamps(1)[0]},0,0,0,1,0,0\n")
    load_error(
        tmp_path,
        r"data\.csv:1: expected at least 8 comma-separated columns 'timestamp, tx, ty, tz, qw, qx, qy, qz', "
        "got 7",
    )


def test_a_ground_truth_of_one_row(tmp_path: Path, track: Path) -> None:
    (track / "pose_groundtruth" / "data.csv").write_text(f"{stamps(1)[0]},0,0,0,1,0,0,0\n")
    load_error(tmp_path, r"pose_groundtruth/data\.csv: 1 ground-truth rows \(expected at least 2")


def test_no_frame_within_the_ground_truths_span(tmp_path: Path) -> None:
    later = [T0_NS + 10**10 + k for k in (0, 10**8)]
    write_track(tmp_path, stamps(3), later, np.stack([pose(), pose()]))
    load_error(
        tmp_path, r"pose_groundtruth/data\.csv: no frame of .*data\.csv within the ground truth's span"
    )


def test_a_ground_truth_gap_wider_than_max_gap_drops_the_frames_in_it(tmp_path: Path) -> None:
    gt_ns = [T0_NS, T0_NS + 40_000_000, T0_NS + 540_000_000]
    write_track(tmp_path, [T0_NS, T0_NS + 300_000_000], gt_ns, np.stack([pose()] * 3))
    seq = mimir.load_sequence(tmp_path, NAME)
    assert seq.dropped == 1 and len(seq.images) == 1
