"""The EuRoC ASL reader: real V1_02 ground truth, cam0's real sensor.yaml, T_BS applied (camera frame, not
body frame), interpolation against scipy's Slerp, nanosecond stamps, and every malformed input."""

from __future__ import annotations

import re
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from evo_data import EUROC_V102, evo_file
from lossvo.data import euroc
from lossvo.data.sequence import DatasetFormatError

# cam0/sensor.yaml of MH_01_easy as the dataset ships it (the same text is quoted by several public EuRoC
# readers, e.g. jskinn/arvet-slam's euroc loader tests, "a genuine yaml file from MH_01_easy, cam0").
SENSOR_YAML = """\
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]

# Camera specific definitions.
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""

T_BS_CAM0 = np.array([
    [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
    [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
    [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
    [0.0, 0.0, 0.0, 1.0],
])  # fmt: skip

T0_NS = 1403715524907143168  # V1_02's first ground-truth stamp
GT_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
    "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
    "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n"
)
TINY_HW = (8, 12)


# --------------------------------------------------------------------------------------------------
# Writers of a tiny layout
# --------------------------------------------------------------------------------------------------


def pose(rotvec: np.ndarray | list[float], t: np.ndarray | list[float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def gt_text(stamps_ns: list[int], poses: list[np.ndarray]) -> str:
    lines = [GT_HEADER]
    for ns, T in zip(stamps_ns, poses, strict=True):
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
        values = [*T[:3, 3], w, x, y, z, *([0.0] * 9)]
        lines.append(f"{ns}," + ",".join(repr(float(v)) for v in values) + "\n")
    return "".join(lines)


def tiny_sensor_yaml(T_BS: np.ndarray = T_BS_CAM0) -> str:
    data = ", ".join(repr(float(v)) for v in T_BS.ravel())
    text = re.sub(r"data: \[.*?\]", f"data: [{data}]", SENSOR_YAML, flags=re.DOTALL)
    return text.replace("resolution: [752, 480]", f"resolution: [{TINY_HW[1]}, {TINY_HW[0]}]")


def write_sequence(
    root: Path,
    name: str,
    frame_ns: list[int],
    gt_ns: list[int] | None,
    gt_poses: list[np.ndarray] | None = None,
    sensor: str | None = None,
) -> Path:
    """ROOT/name/mav0 with cam0 frames (8x12 PNGs) at ``frame_ns``, and a ground truth if ``gt_ns``."""
    mav0 = root / name / "mav0"
    (mav0 / "cam0" / "data").mkdir(parents=True)
    lines = ["#timestamp [ns],filename\n"]
    for ns in frame_ns:
        cv2.imwrite(str(mav0 / "cam0" / "data" / f"{ns}.png"), np.zeros(TINY_HW, np.uint8))
        lines.append(f"{ns},{ns}.png\n")
    (mav0 / "cam0" / "data.csv").write_text("".join(lines))
    (mav0 / "cam0" / "sensor.yaml").write_text(tiny_sensor_yaml() if sensor is None else sensor)
    if gt_ns is not None:
        poses = (
            gt_poses
            if gt_poses is not None
            else [pose([0, 0, 0.01 * k], [k, 0, 0]) for k in range(len(gt_ns))]
        )
        (mav0 / "state_groundtruth_estimate0").mkdir()
        (mav0 / "state_groundtruth_estimate0" / "data.csv").write_text(gt_text(gt_ns, poses))
    return mav0


def ms(k: float) -> int:
    return T0_NS + round(k * 1_000_000)


def raises(match: str):
    return pytest.raises(DatasetFormatError, match=match)


def one_line(excinfo: pytest.ExceptionInfo[DatasetFormatError]) -> None:
    assert "\n" not in str(excinfo.value)


# --------------------------------------------------------------------------------------------------
# Real files
# --------------------------------------------------------------------------------------------------


def quat_wxyz_to_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def test_real_v102_groundtruth_is_parsed() -> None:
    ns, T_w_b = euroc.read_groundtruth(evo_file(EUROC_V102))
    times = euroc.ns_to_seconds(ns)
    assert times.shape == (16702,) and T_w_b.shape == (16702, 4, 4) and T_w_b.dtype == np.float64
    # first line: 1403715524907143168,0.515356,1.996773,0.971104,0.161996,0.789985,-0.205376,0.554528,...
    assert times[0] == pytest.approx(1403715524.907143168, abs=3e-7)
    np.testing.assert_allclose(T_w_b[0, :3, 3], [0.515356, 1.996773, 0.971104], atol=1e-12)
    np.testing.assert_allclose(
        T_w_b[0, :3, :3], quat_wxyz_to_matrix(0.161996, 0.789985, -0.205376, 0.554528), atol=1e-12
    )
    # last line: 1403715608412143104,0.524978,1.987190,0.971496,0.159222,0.790116,-0.206917,0.554572,...
    assert times[-1] == pytest.approx(1403715608.412143104, abs=3e-7)
    np.testing.assert_allclose(T_w_b[-1, :3, 3], [0.524978, 1.987190, 0.971496], atol=1e-12)
    np.testing.assert_allclose(
        T_w_b[-1, :3, :3], quat_wxyz_to_matrix(0.159222, 0.790116, -0.206917, 0.554572), atol=1e-12
    )
    assert np.median(np.diff(times)) == pytest.approx(0.005, abs=1e-6)  # 200 Hz
    R = T_w_b[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_array_equal(T_w_b[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(times), 4)))


@pytest.mark.parametrize("opencv_header", [False, True])
def test_real_cam0_sensor_yaml(tmp_path: Path, opencv_header: bool) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text(("%YAML:1.0\n" if opencv_header else "") + SENSOR_YAML)
    K, distortion, T_BS, size = euroc.read_sensor(path)
    np.testing.assert_array_equal(K, [[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1]])
    np.testing.assert_array_equal(distortion, [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
    np.testing.assert_array_equal(T_BS, T_BS_CAM0)
    assert size == (480, 752)


# --------------------------------------------------------------------------------------------------
# Timestamps
# --------------------------------------------------------------------------------------------------


def test_nanosecond_stamps_keep_sub_microsecond_order(tmp_path: Path) -> None:
    stamps = [T0_NS + 300 * k for k in range(40)]  # 0.3 µs apart, near 1.4e18 ns
    path = tmp_path / "data.csv"
    path.write_text("#timestamp [ns],filename\n" + "".join(f"{ns},{ns}.png\n" for ns in stamps))
    ns, names = euroc.read_camera_stamps(path)
    times = euroc.ns_to_seconds(ns)
    assert names == [f"{ns}.png" for ns in stamps]
    assert times.dtype == np.float64
    assert np.all(np.diff(times) > 0)
    for t, ns in zip(times, stamps, strict=True):
        assert abs(Fraction(float(t)) - Fraction(ns, 10**9)) <= Fraction(float(np.spacing(t)))
    np.testing.assert_allclose(np.diff(times), 3e-7, atol=np.spacing(times[0]))


# --------------------------------------------------------------------------------------------------
# Poses: T_BS applied, interpolation
# --------------------------------------------------------------------------------------------------


def test_camera_frame_relative_motion_applies_T_BS(tmp_path: Path) -> None:
    body = [pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), pose([0.05, -0.2, 0.3], [0.4, 0.1, -0.2])]
    body += [pose([0.1, -0.1, 0.5], [0.8, 0.3, -0.1])]
    gt_ns = [ms(0), ms(5), ms(10)]
    write_sequence(tmp_path, "V1_02_medium", gt_ns, gt_ns, body)
    seq = euroc.load_sequence(tmp_path, "V1_02_medium")
    assert seq.dropped == 0 and seq.poses is not None
    np.testing.assert_allclose(seq.poses[0], body[0] @ T_BS_CAM0, atol=1e-12)
    relative = np.linalg.inv(seq.poses[0]) @ seq.poses[1]
    camera_motion = np.linalg.inv(T_BS_CAM0) @ np.linalg.inv(body[0]) @ body[1] @ T_BS_CAM0
    body_motion = np.linalg.inv(body[0]) @ body[1]
    np.testing.assert_allclose(relative, camera_motion, atol=1e-12)
    assert np.abs(relative - body_motion).max() > 0.1


def test_interpolation_at_midpoint_matches_slerp_and_linear(tmp_path: Path) -> None:
    body = [pose([0.1, 0.2, -0.3], [1.0, 2.0, 3.0]), pose([0.15, 0.1, -0.2], [1.2, 1.8, 3.4])]
    write_sequence(tmp_path, "MH_01_easy", [ms(2.5), ms(4)], [ms(0), ms(5)], body)
    seq = euroc.load_sequence(tmp_path, "MH_01_easy")
    assert seq.poses is not None
    slerp = Slerp([0.0, 5.0], Rotation.from_matrix(np.stack([T[:3, :3] for T in body])))
    for k, t_ms in enumerate((2.5, 4.0)):
        expected_body = np.eye(4)
        expected_body[:3, :3] = slerp([t_ms]).as_matrix()[0]
        w = t_ms / 5.0
        expected_body[:3, 3] = (1 - w) * body[0][:3, 3] + w * body[1][:3, 3]
        np.testing.assert_allclose(seq.poses[k], expected_body @ T_BS_CAM0, atol=1e-9)


def test_interpolation_about_one_axis_halves_the_angle() -> None:
    a, b = 0.2, 0.9
    T0, T1 = pose([0, 0, a], [0, 0, 0]), pose([0, 0, b], [2, -4, 6])
    mid = euroc.interpolate_poses(T0[None], T1[None], np.array([0.5]))[0]
    c, s = np.cos((a + b) / 2), np.sin((a + b) / 2)
    np.testing.assert_allclose(mid[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(mid[:3, 3], [1, -2, 3], atol=1e-12)


def test_frames_outside_span_or_across_gap_are_dropped(tmp_path: Path) -> None:
    gt_ns = [ms(k) for k in (0, 5, 10, 15, 50, 55, 60)]  # 15 -> 50 ms: a gap of 35 ms
    frames = [ms(k) for k in (-3, 0, 7, 30, 52, 60, 61)]
    write_sequence(tmp_path, "V2_01_easy", frames, gt_ns)
    seq = euroc.load_sequence(tmp_path, "V2_01_easy")
    assert seq.dropped == 3  # -3 (before), 30 (in the gap), 61 (after)
    assert [p.name for p in seq.images] == [f"{ms(k)}.png" for k in (0, 7, 52, 60)]
    np.testing.assert_allclose(seq.times - seq.times[0], [0.0, 0.007, 0.052, 0.060], atol=1e-6)
    assert seq.poses is not None and seq.poses.shape == (4, 4, 4)
    wider = euroc.load_sequence(tmp_path, "V2_01_easy", max_gap=0.05)
    assert wider.dropped == 2


def test_load_sequence_camera(tmp_path: Path) -> None:
    write_sequence(tmp_path, "MH_01_easy", [ms(0), ms(5)], [ms(0), ms(5)])
    seq = euroc.load_sequence(tmp_path, "MH_01_easy")
    assert seq.name == "MH_01_easy" and seq.size == TINY_HW
    np.testing.assert_array_equal(seq.K, [[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1]])
    np.testing.assert_array_equal(seq.distortion, [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0])
    times = np.array([1403715524.907143168, 1403715524.912143168])
    np.testing.assert_allclose(seq.times, times, atol=3e-7, rtol=0)


def test_list_sequences_and_optional_poses(tmp_path: Path) -> None:
    write_sequence(tmp_path, "V1_02_medium", [ms(0), ms(5)], None)
    write_sequence(tmp_path, "MH_01_easy", [ms(0), ms(5)], [ms(0), ms(5)])
    (tmp_path / "not_a_sequence").mkdir()
    assert euroc.list_sequences(tmp_path) == ["MH_01_easy", "V1_02_medium"]
    seq = euroc.load_sequence(tmp_path, "V1_02_medium", require_poses=False)
    assert seq.poses is None and len(seq.images) == 2 and seq.dropped == 0


# --------------------------------------------------------------------------------------------------
# Bad inputs
# --------------------------------------------------------------------------------------------------


def test_missing_root_and_unknown_sequence(tmp_path: Path) -> None:
    with raises(r"does-not-exist: dataset root does not exist") as e:
        euroc.load_sequence(tmp_path / "does-not-exist", "MH_01_easy")
    one_line(e)
    write_sequence(tmp_path, "MH_01_easy", [ms(0)], [ms(0), ms(5)])
    write_sequence(tmp_path, "V1_01_easy", [ms(0)], [ms(0), ms(5)])
    with raises(
        r"V1_02_medium/mav0: sequence 'V1_02_medium' not found .*found: MH_01_easy, V1_01_easy\)"
    ) as e:
        euroc.load_sequence(tmp_path, "V1_02_medium")
    one_line(e)


@pytest.mark.parametrize(
    ("relative", "match"),
    [
        ("cam0/data.csv", r"cam0/data\.csv: cannot read camera list"),
        ("cam0/sensor.yaml", r"cam0/sensor\.yaml: cannot read camera calibration"),
        ("state_groundtruth_estimate0/data.csv", r"state_groundtruth_estimate0/data\.csv: no ground truth"),
        (f"cam0/data/{ms(5)}.png", rf"cam0/data\.csv:3: frame .*{ms(5)}\.png does not exist"),
    ],
)
def test_missing_files(tmp_path: Path, relative: str, match: str) -> None:
    mav0 = write_sequence(tmp_path, "MH_01_easy", [ms(0), ms(5)], [ms(0), ms(5)])
    (mav0 / relative).unlink()
    with raises(match) as e:
        euroc.load_sequence(tmp_path, "MH_01_easy")
    one_line(e)


@pytest.mark.parametrize(
    ("body", "match"),
    [
        (f"{T0_NS},a.png\n{T0_NS + 5},b.png,extra\n", r"data\.csv:3: expected 2 comma-separated columns"),
        (
            f"{T0_NS},a.png\n1.4037155249e18,b.png\n",
            r"data\.csv:3: expected a timestamp in integer nanoseconds",
        ),
        (
            f"{T0_NS},a.png\n{T0_NS - 1},b.png\n",
            r"data\.csv:3: timestamp .* does not follow .*strictly increasing",
        ),
        (f"{T0_NS},a.png\n{T0_NS},b.png\n", r"data\.csv:3: timestamp .* does not follow"),
        (f"{T0_NS},\n", r"data\.csv:2: empty file name"),
        ("", r"data\.csv: no data lines in camera list"),
    ],
)
def test_bad_camera_list(tmp_path: Path, body: str, match: str) -> None:
    path = tmp_path / "data.csv"
    path.write_text("#timestamp [ns],filename\n" + body)
    with raises(match) as e:
        euroc.read_camera_stamps(path)
    one_line(e)


def _gt_line(ns: int | str, quat: str = "1,0,0,0", extra: int = 9) -> str:
    return f"{ns},0,0,0,{quat}" + ",0" * extra + "\n"


@pytest.mark.parametrize(
    ("body", "match"),
    [
        (
            _gt_line(T0_NS) + _gt_line(T0_NS + 5_000_000, extra=8),
            r"data\.csv:3: expected 17 comma-separated columns",
        ),
        (
            _gt_line(T0_NS) + _gt_line(T0_NS + 5_000_000, quat="1,x,0,0"),
            r"data\.csv:3: expected a number, got 'x'",
        ),
        (
            _gt_line(T0_NS) + _gt_line(T0_NS + 5_000_000, quat="1,nan,0,0"),
            r"data\.csv:3: expected a finite number",
        ),
        (_gt_line(T0_NS) + _gt_line(T0_NS - 5_000_000), r"data\.csv:3: timestamp .* does not follow"),
        (_gt_line(T0_NS) + _gt_line(T0_NS), r"data\.csv:3: timestamp .* does not follow"),
        (
            _gt_line(T0_NS) + _gt_line(T0_NS + 5),
            r"data\.csv:3: timestamp .* is 5 ns after .*differ as float64",
        ),
        (_gt_line(T0_NS) + _gt_line("14037.5"), r"data\.csv:3: expected a timestamp in integer nanoseconds"),
        (
            _gt_line(T0_NS) + _gt_line(T0_NS + 5_000_000, quat="2,0,0,0"),
            r"data\.csv:3: quaternion q_RS of norm 2",
        ),
        (_gt_line(T0_NS), r"data\.csv: one ground-truth row"),
        ("", r"data\.csv: no data lines in ground truth"),
    ],
)
def test_bad_groundtruth(tmp_path: Path, body: str, match: str) -> None:
    path = tmp_path / "data.csv"
    path.write_text(GT_HEADER + body)
    with raises(match) as e:
        euroc.read_groundtruth(path)
    one_line(e)


def _without_key(key: str) -> str:
    pattern = r"T_BS:\n(  .*\n|        .*\n)+" if key == "T_BS" else rf"{key}: .*\n"
    text, n = re.subn(pattern, "", SENSOR_YAML)
    assert n == 1
    return text


def _with_T_BS(T: np.ndarray) -> str:
    return re.sub(r"data: \[.*?\]", "data: [" + ", ".join(map(repr, T.ravel().tolist())) + "]", SENSOR_YAML,
                  flags=re.DOTALL)  # fmt: skip


def _scaled_T_BS() -> np.ndarray:
    T = T_BS_CAM0.copy()
    T[:3, :3] *= 1.01
    return T


def _reflected_T_BS() -> np.ndarray:
    T = T_BS_CAM0.copy()
    T[:3, 0] *= -1
    return T


def _bad_last_row() -> np.ndarray:
    T = T_BS_CAM0.copy()
    T[3, 0] = 0.5
    return T


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (_without_key("intrinsics"), r"sensor\.yaml: key 'intrinsics' missing"),
        (_without_key("T_BS"), r"sensor\.yaml: key 'T_BS' missing"),
        (_without_key("resolution"), r"sensor\.yaml: key 'resolution' missing"),
        (_without_key("distortion_coefficients"), r"sensor\.yaml: key 'distortion_coefficients' missing"),
        (
            SENSOR_YAML.replace("367.215, 248.375]", "367.215]"),
            r"sensor\.yaml: key 'intrinsics': expected \[fu",
        ),
        (SENSOR_YAML.replace("[752, 480]", "[752.5, 480]"), r"sensor\.yaml: key 'resolution': expected two"),
        (
            SENSOR_YAML.replace("0.0, 0.0, 0.0, 1.0]", "0.0, 0.0, 0.0]"),
            r"sensor\.yaml: key 'data': expected the 16",
        ),
        (SENSOR_YAML.replace("rows: 4", "rows: 3"), r"sensor\.yaml: key 'T_BS\.rows': expected 4"),
        (_with_T_BS(_scaled_T_BS()), r"sensor\.yaml: key 'T_BS': rotation block is not a rotation"),
        (_with_T_BS(_reflected_T_BS()), r"sensor\.yaml: key 'T_BS': rotation block .*det = -1"),
        (_with_T_BS(_bad_last_row()), r"sensor\.yaml: key 'T_BS': last row .*expected 0 0 0 1"),
        (
            SENSOR_YAML.replace("radial-tangential", "equidistant"),
            r"key 'distortion_model': expected 'radial-t",
        ),
        (SENSOR_YAML.replace("camera_model: pinhole", "camera_model: omni"), r"key 'camera_model': expected"),
        (SENSOR_YAML.replace("rate_hz: 20", "rate_hz: [20"), r"sensor\.yaml:\d+: not valid YAML"),
        ("- 1\n- 2\n", r"sensor\.yaml: expected a YAML mapping"),
    ],
)
def test_bad_sensor_yaml(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text(text)
    with raises(match) as e:
        euroc.read_sensor(path)
    one_line(e)


def test_frame_size_must_match_sensor_resolution(tmp_path: Path) -> None:
    write_sequence(tmp_path, "MH_01_easy", [ms(0)], [ms(0), ms(5)], sensor=SENSOR_YAML)
    with raises(
        rf"{ms(0)}\.png: frame of 12x8 pixels, but .*sensor\.yaml key 'resolution' says 752x480"
    ) as e:
        euroc.load_sequence(tmp_path, "MH_01_easy")
    one_line(e)


def test_no_frame_within_groundtruth_span(tmp_path: Path) -> None:
    write_sequence(tmp_path, "MH_01_easy", [ms(100), ms(105)], [ms(0), ms(5)])
    with raises(
        r"state_groundtruth_estimate0/data\.csv: no frame of .*data\.csv within the ground truth's span"
    ) as e:
        euroc.load_sequence(tmp_path, "MH_01_easy")
    one_line(e)
