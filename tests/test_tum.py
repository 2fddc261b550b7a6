"""lossvo.data.tum: the real freiburg1_xyz ground truth, association by time against a brute-force greedy, the
Freiburg cameras, and every bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from evo_data import TUM_FR1_XYZ, evo_file
from lossvo.console import UserError
from lossvo.data import tum
from lossvo.data.sequence import DatasetFormatError

FR1 = "rgbd_dataset_freiburg1_xyz"
HEIGHT, WIDTH = 8, 12


# --------------------------------------------------------------------------------------------------
# Independent expectations
# --------------------------------------------------------------------------------------------------


def quaternion_matrix(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """(3, 3) rotation of a quaternion (x, y, z, w), normalised, by the textbook formula."""
    n = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    x, y, z, w = qx / n, qy / n, qz / n, qw / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def rows_of(path: Path) -> list[list[float]]:
    """The numbers of every non-comment, non-empty line of a TUM text file."""
    lines = path.read_text().splitlines()
    return [[float(v) for v in line.split()] for line in lines if line.strip() and not line.startswith("#")]


def brute_force_associate(
    frames: np.ndarray, stamps: np.ndarray, max_difference: float
) -> list[tuple[int, int]]:
    """TUM associate.py's rule, O(N*M): every pair closer than max_difference, sorted by (difference, frame,
    stamp), taken greedily with each frame and each stamp used once; returned sorted by frame."""
    difference = np.abs(frames[:, None] - stamps[None, :])
    candidates = sorted(
        (float(difference[i, j]), int(i), int(j))
        for i, j in zip(*np.nonzero(difference < max_difference), strict=True)
    )
    free_frames, free_stamps = set(range(len(frames))), set(range(len(stamps)))
    pairs = []
    for _, i, j in candidates:
        if i in free_frames and j in free_stamps:
            free_frames.remove(i)
            free_stamps.remove(j)
            pairs.append((i, j))
    return sorted(pairs)


def pairs_of(frames: np.ndarray, stamps: np.ndarray, max_difference: float = 0.02) -> list[tuple[int, int]]:
    frame_index, gt_index = tum.associate(frames, stamps, max_difference)
    assert frame_index.dtype == np.int64 and gt_index.dtype == np.int64
    return list(zip(frame_index.tolist(), gt_index.tolist(), strict=True))


# --------------------------------------------------------------------------------------------------
# Layouts
# --------------------------------------------------------------------------------------------------


def write_frames(folder: Path, times: np.ndarray, header: bool = True) -> list[Path]:
    """rgb.txt (with TUM's three comment lines) and one 8x12 PNG per timestamp; the frame paths."""
    (folder / "rgb").mkdir(parents=True, exist_ok=True)
    lines = ["# color images", f"# file: '{folder.name}.bag'", "# timestamp filename"] if header else []
    paths = []
    for t in times:
        name = f"rgb/{t:.6f}.png"
        lines.append(f"{t:.6f} {name}")
        paths.append(folder / name)
        cv2.imwrite(str(paths[-1]), np.full((HEIGHT, WIDTH, 3), 128, np.uint8))
    (folder / "rgb.txt").write_text("\n".join(lines) + "\n")
    return paths


def write_groundtruth(folder: Path, times: np.ndarray) -> np.ndarray:
    """groundtruth.txt with one row per timestamp (a translation that grows with time, rotations about z);
    the (M, 4, 4) poses it holds, built here."""
    angles = np.linspace(0.0, 1.0, len(times))
    q = np.stack([np.zeros_like(angles), np.zeros_like(angles), np.sin(angles / 2), np.cos(angles / 2)], 1)
    t = np.stack([times - times[0], 2 * (times - times[0]), np.full_like(times, 0.5)], 1)
    lines = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    lines += [" ".join(f"{v:.10f}" for v in (s, *ti, *qi)) for s, ti, qi in zip(times, t, q, strict=True)]
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    poses = np.tile(np.eye(4), (len(times), 1, 1))
    for k, (ti, qi) in enumerate(zip(t, q, strict=True)):  # building expectations
        poses[k, :3, :3] = quaternion_matrix(*qi)
        poses[k, :3, 3] = ti
    return poses


@pytest.fixture
def tiny_tum(tmp_path: Path) -> Path:
    """ROOT with one freiburg1 sequence: 10 frames at 30 Hz inside 100 Hz ground truth."""
    folder = tmp_path / FR1
    write_frames(folder, 100.0 + np.arange(10) / 30)
    write_groundtruth(folder, 99.9 + np.arange(60) / 100)
    return tmp_path


# --------------------------------------------------------------------------------------------------
# The real ground truth
# --------------------------------------------------------------------------------------------------


def test_real_groundtruth_parsed() -> None:
    path = evo_file(TUM_FR1_XYZ)
    rows = rows_of(path)
    times, poses = tum.read_groundtruth(path)
    assert len(rows) == 3000 and times.shape == (3000,) and poses.shape == (3000, 4, 4)
    assert times.dtype == np.float64 and poses.dtype == np.float64
    first = path.read_text().splitlines()[3].split()
    assert times[0] == float(first[0])
    np.testing.assert_array_equal(poses[0, :3, 3], [float(v) for v in first[1:4]])
    np.testing.assert_allclose(poses[0, :3, :3], quaternion_matrix(*map(float, first[4:8])), atol=1e-12)
    table = np.array(rows)
    np.testing.assert_array_equal(times, table[:, 0])
    np.testing.assert_array_equal(poses[:, :3, 3], table[:, 1:4])
    R = poses[:, :3, :3]
    np.testing.assert_allclose(R.transpose(0, 2, 1) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_array_equal(poses[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (3000, 4)))


@pytest.fixture(scope="module")
def real_layout(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """ROOT/rgbd_dataset_freiburg1_xyz with the real ground truth and ~30 Hz frames with 3 ms of jitter that
    start 0.3 s before the ground truth and end 0.3 s after it; the frame times as written."""
    root = tmp_path_factory.mktemp("tum")
    folder = root / FR1
    folder.mkdir()
    shutil.copy(evo_file(TUM_FR1_XYZ), folder / "groundtruth.txt")
    gt = np.array(rows_of(folder / "groundtruth.txt"))[:, 0]
    rng = np.random.default_rng(0)
    nominal = np.arange(gt[0] - 0.3, gt[-1] + 0.3, 1 / 30)
    times = nominal + rng.uniform(-0.003, 0.003, nominal.size)
    write_frames(folder, times)
    return root, np.array([float(f"{t:.6f}") for t in times])


def test_association_on_real_groundtruth(real_layout: tuple[Path, np.ndarray]) -> None:
    root, frame_times = real_layout
    gt_path = root / FR1 / "groundtruth.txt"
    table = np.array(rows_of(gt_path))
    gt_times = table[:, 0]
    expected = brute_force_associate(frame_times, gt_times, 0.02)
    assert pairs_of(frame_times, gt_times) == expected
    frames = np.array([i for i, _ in expected])
    stamps = np.array([j for _, j in expected])
    # At 30 Hz against 100 Hz no two frames compete: each takes its nearest stamp, less than 0.02 s away.
    nearest = np.abs(frame_times[frames, None] - gt_times[None, :]).argmin(axis=1)
    np.testing.assert_array_equal(stamps, nearest)
    assert np.all(np.abs(frame_times[frames] - gt_times[stamps]) < 0.02)

    seq = tum.load_sequence(root, FR1)
    outside = (frame_times < gt_times[0] - 0.02) | (frame_times > gt_times[-1] + 0.02)
    assert outside[:5].all() and outside[-5:].all()
    assert seq.dropped == len(frame_times) - len(expected) >= outside.sum() + 1  # + frames in the 0.11 s gap
    np.testing.assert_array_equal(seq.times, frame_times[frames])
    assert seq.images == [root / FR1 / f"rgb/{t:.6f}.png" for t in frame_times[frames]]
    built = np.tile(np.eye(4), (len(stamps), 1, 1))
    built[:, :3, 3] = table[stamps, 1:4]
    for k, j in enumerate(stamps):  # building expectations
        built[k, :3, :3] = quaternion_matrix(*table[j, 4:8])
    assert seq.poses is not None and seq.poses.dtype == np.float64
    np.testing.assert_allclose(seq.poses, built, atol=1e-12)
    assert seq.size == (HEIGHT, WIDTH)


# --------------------------------------------------------------------------------------------------
# Association: edge cases and the brute force on random stamps
# --------------------------------------------------------------------------------------------------


def test_a_tie_between_two_stamps_takes_the_earlier_stamp() -> None:
    assert pairs_of(np.array([1.0]), np.array([0.9921875, 1.0078125])) == [(0, 0)]


def test_a_tie_between_two_frames_gives_the_stamp_to_the_earlier_frame() -> None:
    assert pairs_of(np.array([0.9921875, 1.0078125]), np.array([1.0])) == [(0, 0)]


def test_a_frame_between_two_stamps_takes_the_nearer() -> None:
    stamps = np.arange(5) / 100
    assert pairs_of(np.array([0.013, 0.027]), stamps) == [(0, 1), (1, 3)]


def test_frames_outside_the_span_are_dropped() -> None:
    stamps = 10.0 + np.arange(100) / 100
    frames = np.array([9.5, 9.979, 9.985, 10.5, 10.995, 11.02, 11.5])
    assert pairs_of(frames, stamps) == [(2, 0), (3, 50), (4, 99)]


def test_a_gap_longer_than_the_tolerance_drops_the_frames_in_it() -> None:
    stamps = np.concatenate([np.arange(101) / 100, 1.2 + np.arange(81) / 100])  # nothing in (1.0, 1.2)
    frames = np.array([0.993, 1.015, 1.05, 1.1, 1.15, 1.19])
    assert pairs_of(frames, stamps) == [(0, 99), (1, 100), (5, 101)]


def test_two_frames_competing_for_one_stamp() -> None:
    # Both are nearest to stamp 0: the nearer frame wins it, the other takes its next stamp if close enough.
    assert pairs_of(np.array([0.001, 0.005]), np.array([0.0, 0.015])) == [(0, 0), (1, 1)]
    assert pairs_of(np.array([0.001, 0.005]), np.array([0.0, 0.03])) == [(0, 0)]


def test_the_bound_is_strict() -> None:
    assert pairs_of(np.array([0.5]), np.array([0.0, 1.0]), max_difference=0.5) == []
    assert pairs_of(np.array([0.5]), np.array([0.0]), max_difference=0.5000001) == [(0, 0)]


def test_empty_inputs() -> None:
    assert pairs_of(np.zeros(0), np.arange(3.0)) == []
    assert pairs_of(np.arange(3.0), np.zeros(0)) == []


@pytest.mark.parametrize("seed", range(40))
def test_matches_the_brute_force_greedy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    # Stamps on a 1/256 s grid, so that exact ties in the difference are frequent.
    frames = np.unique(rng.integers(0, 300, rng.integers(1, 60))) / 256
    stamps = np.unique(rng.integers(0, 300, rng.integers(1, 60))) / 256
    max_difference = float(rng.choice([0.005, 0.02, 0.05, 0.2]))
    assert pairs_of(frames, stamps, max_difference) == brute_force_associate(frames, stamps, max_difference)


def test_unsorted_stamps_are_refused() -> None:
    with pytest.raises(UserError, match="strictly increasing"):
        tum.associate(np.array([0.0]), np.array([0.0, 0.0]))


# --------------------------------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------------------------------

# TUM's calibration table (file_formats page), 4 digits: fx fy cx cy and d0..d4 = k1 k2 p1 p2 k3.
TUM_TABLE = {
    "freiburg1": ([517.3, 516.5, 318.6, 255.3], [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]),
    "freiburg2": ([520.9, 521.0, 325.1, 249.7], [0.2312, -0.7849, -0.0033, -0.0001, 0.9172]),
    "freiburg3": ([535.4, 539.2, 320.1, 247.6], [0.0, 0.0, 0.0, 0.0, 0.0]),
}


@pytest.mark.parametrize(
    ("name", "key"),
    [
        ("rgbd_dataset_freiburg1_xyz", "freiburg1"),
        ("rgbd_dataset_freiburg2_pioneer_360", "freiburg2"),
        ("rgbd_dataset_freiburg3_long_office_household", "freiburg3"),
        ("fr1_desk", "freiburg1"),
        ("FR2-desk", "freiburg2"),
        ("my_fr3", "freiburg3"),
    ],
)
def test_camera_by_name_matches_tums_table(name: str, key: str) -> None:
    K, distortion = tum.camera(name)
    (fx, fy, cx, cy), d = TUM_TABLE[key]
    np.testing.assert_allclose(K, [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], atol=0.05 + 1e-9)
    np.testing.assert_allclose(distortion, d, atol=5e-5 + 1e-12)
    assert K.dtype == np.float64 and distortion.shape == (5,)


@pytest.mark.parametrize("name", ["rgbd_dataset_freiburg4_xyz", "fr12", "office", "afr1"])
def test_unknown_camera_names_the_sequence_and_the_keys(name: str) -> None:
    with pytest.raises(DatasetFormatError) as error:
        tum.camera(name)
    message = str(error.value)
    assert "\n" not in message and repr(name) in message
    assert "its K (3x3" in message and "distortion (k1" in message


def test_camera_scaled_to_frames_of_another_size() -> None:
    full, _ = tum.camera(FR1)
    half, _ = tum.camera(FR1, size=(240, 320))
    np.testing.assert_allclose(half[:2, :2], full[:2, :2] / 2)
    np.testing.assert_allclose(half[:2, 2], (full[:2, 2] + 0.5) / 2 - 0.5)
    K = np.diag([400.0, 400.0, 1.0])
    np.testing.assert_array_equal(
        tum.camera(FR1, K=K, size=(240, 320))[0], K
    )  # an override is taken as given


def test_camera_overrides() -> None:
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    got_K, got_d = tum.camera("office", K=K)
    np.testing.assert_array_equal(got_K, K)
    np.testing.assert_array_equal(got_d, np.zeros(5))
    got_K, got_d = tum.camera(FR1, distortion=np.array([0.1, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(got_K[0, 0], 517.3, atol=0.05)
    np.testing.assert_array_equal(got_d, [0.1, 0.0, 0.0, 0.0])
    with pytest.raises(UserError, match="K of shape"):
        tum.camera(FR1, K=np.eye(2))


def test_load_sequence_with_an_unknown_camera(tmp_path: Path) -> None:
    folder = tmp_path / "office"
    write_frames(folder, 100.0 + np.arange(3) / 30)
    write_groundtruth(folder, 100.0 + np.arange(20) / 100)
    with pytest.raises(DatasetFormatError, match="'office': unknown camera"):
        tum.load_sequence(tmp_path, "office")
    K = np.diag([400.0, 400.0, 1.0])
    seq = tum.load_sequence(tmp_path, "office", K=K, distortion=np.zeros(4))
    np.testing.assert_array_equal(seq.K, K)
    assert seq.distortion.shape == (4,)


# --------------------------------------------------------------------------------------------------
# Sequences
# --------------------------------------------------------------------------------------------------


def test_tiny_sequence(tiny_tum: Path) -> None:
    seq = tum.load_sequence(tiny_tum, FR1)
    folder = tiny_tum / FR1
    frames = np.array([float(f"{t:.6f}") for t in 100.0 + np.arange(10) / 30])
    stamps = 99.9 + np.arange(60) / 100
    expected_poses = write_groundtruth(folder, stamps)
    nearest = np.rint((frames - 99.9) * 100).astype(int)
    assert seq.name == FR1 and seq.dropped == 0 and seq.size == (HEIGHT, WIDTH)
    np.testing.assert_array_equal(seq.times, frames)
    assert seq.images == [folder / f"rgb/{t:.6f}.png" for t in frames]
    np.testing.assert_allclose(seq.poses, expected_poses[nearest], atol=1e-9)
    # frames of 8x12 pixels: a resized copy of 480x640 frames, K scaled as cv2.resize maps pixel centres
    np.testing.assert_allclose(
        seq.K[0], [517.306408 * WIDTH / 640, 0, (318.643040 + 0.5) * WIDTH / 640 - 0.5]
    )
    np.testing.assert_allclose(
        seq.K[1, 1:], [516.469215 * HEIGHT / 480, (255.313989 + 0.5) * HEIGHT / 480 - 0.5]
    )


def test_frames_outside_the_groundtruth_are_counted(tmp_path: Path) -> None:
    folder = tmp_path / FR1
    frames = 100.0 + np.arange(20) / 30  # 100.0 .. 100.633
    write_frames(folder, frames)
    expected_poses = write_groundtruth(folder, 100.2 + np.arange(21) / 100)  # 100.2 .. 100.4
    seq = tum.load_sequence(tmp_path, FR1)
    inside = [k for k, t in enumerate(frames) if 100.18 < t < 100.42]
    assert seq.dropped == 20 - len(inside) and len(seq.images) == len(inside)
    np.testing.assert_allclose(seq.times, [float(f"{frames[k]:.6f}") for k in inside])
    nearest = np.rint((seq.times - 100.2) * 100).astype(int)
    np.testing.assert_allclose(seq.poses, expected_poses[nearest], atol=1e-9)


def test_without_groundtruth(tiny_tum: Path) -> None:
    (tiny_tum / FR1 / "groundtruth.txt").unlink()
    seq = tum.load_sequence(tiny_tum, FR1, require_poses=False)
    assert seq.poses is None and len(seq.images) == 10 and seq.dropped == 0


def test_list_sequences(tiny_tum: Path) -> None:
    write_frames(tiny_tum / "rgbd_dataset_freiburg2_desk", np.array([1.0]))
    (tiny_tum / "not_a_sequence").mkdir()
    assert tum.list_sequences(tiny_tum) == [FR1, "rgbd_dataset_freiburg2_desk"]


def test_comments_and_blank_lines_are_skipped(tmp_path: Path) -> None:
    path = tmp_path / "rgb.txt"
    path.write_text("# color images\n\n1.5 rgb/1.5.png\n  # indented comment\n2.5 rgb/2.5.png\n")
    times, names = tum.read_rgb_list(path)
    np.testing.assert_array_equal(times, [1.5, 2.5])
    assert names == ["rgb/1.5.png", "rgb/2.5.png"]


def test_quaternions_are_normalised(tmp_path: Path) -> None:
    path = tmp_path / "groundtruth.txt"
    path.write_text("1.0 1 2 3 0 0 0.6 0.802\n")  # norm 1.0012
    _, poses = tum.read_groundtruth(path)
    np.testing.assert_allclose(poses[0, :3, :3], quaternion_matrix(0, 0, 0.6, 0.802), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(poses[0, :3, :3]), 1.0, atol=1e-12)


# --------------------------------------------------------------------------------------------------
# Bad input: one line naming the file (and line) and what was expected
# --------------------------------------------------------------------------------------------------


def raises_one_line(call: object, *fragments: str) -> str:
    assert callable(call)
    with pytest.raises(DatasetFormatError) as error:
        call()
    message = str(error.value)
    assert "\n" not in message, message
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    return message


@pytest.mark.parametrize(
    ("text", "line", "expected"),
    [
        ("# c\n1.0 rgb/a.png extra\n", 2, "expected 2 fields"),
        ("1.0\n", 1, "expected 2 fields"),
        ("# c\n# c\n1.0 a.png\nabc b.png\n", 4, "'abc'"),
        ("1.0 a.png\ninf b.png\n", 2, "expected a timestamp"),
        ("1.0 a.png\n2.0 b.png\n1.5 c.png\n", 3, "does not follow"),
        ("1.0 a.png\n1.0 b.png\n", 2, "strictly increasing"),
    ],
)
def test_bad_rgb_list(tmp_path: Path, text: str, line: int, expected: str) -> None:
    path = tmp_path / "rgb.txt"
    path.write_text(text)
    raises_one_line(lambda: tum.read_rgb_list(path), f"{path}:{line}:", expected)


@pytest.mark.parametrize("text", ["", "# only comments\n\n"])
def test_empty_rgb_list(tmp_path: Path, text: str) -> None:
    path = tmp_path / "rgb.txt"
    path.write_text(text)
    raises_one_line(lambda: tum.read_rgb_list(path), str(path), "no frames")


GOOD = "1.0 0 0 0 0 0 0 1"


@pytest.mark.parametrize(
    ("text", "line", "expected"),
    [
        (f"# c\n{GOOD}\n2.0 0 0 0 0 0 1\n", 3, "expected 8 numbers"),
        (f"{GOOD} 5\n", 1, "got 9 fields"),
        (f"{GOOD}\n2.0 0 0 x 0 0 0 1\n", 2, "'x'"),
        (f"{GOOD}\n2.0 0 0 nan 0 0 0 1\n", 2, "expected 8 numbers"),
        (f"{GOOD}\n0.5 0 0 0 0 0 0 1\n", 2, "does not follow"),
        (f"{GOOD}\n{GOOD}\n", 2, "strictly increasing"),
        (f"{GOOD}\n2.0 0 0 0 0 0 0 2\n", 2, "unit quaternion"),
        (f"{GOOD}\n2.0 0 0 0 0 0 0 0\n", 2, "norm 0"),
    ],
)
def test_bad_groundtruth(tmp_path: Path, text: str, line: int, expected: str) -> None:
    path = tmp_path / "groundtruth.txt"
    path.write_text(text)
    raises_one_line(lambda: tum.read_groundtruth(path), f"{path}:{line}:", expected)


def test_empty_or_missing_groundtruth_file(tmp_path: Path) -> None:
    path = tmp_path / "groundtruth.txt"
    path.write_text("# ground truth\n")
    raises_one_line(lambda: tum.read_groundtruth(path), str(path), "no poses")
    path.unlink()
    raises_one_line(lambda: tum.read_groundtruth(path), str(path), "cannot read ground truth")


def test_missing_root(tmp_path: Path) -> None:
    raises_one_line(
        lambda: tum.list_sequences(tmp_path / "nowhere"), str(tmp_path / "nowhere"), "does not exist"
    )
    raises_one_line(lambda: tum.load_sequence(tmp_path / "nowhere", FR1), "does not exist")


def test_missing_sequence_names_the_ones_found(tiny_tum: Path) -> None:
    raises_one_line(
        lambda: tum.load_sequence(tiny_tum, "rgbd_dataset_freiburg1_desk"),
        str(tiny_tum / "rgbd_dataset_freiburg1_desk"),
        "not found",
        f"found: {FR1}",
    )


def test_missing_rgb_list(tiny_tum: Path) -> None:
    path = tiny_tum / FR1 / "rgb.txt"
    path.unlink()
    raises_one_line(
        lambda: tum.load_sequence(tiny_tum, FR1), str(path), "not found", "expected ROOT/<sequence>/rgb.txt"
    )


def test_missing_groundtruth(tiny_tum: Path) -> None:
    path = tiny_tum / FR1 / "groundtruth.txt"
    path.unlink()
    raises_one_line(lambda: tum.load_sequence(tiny_tum, FR1), str(path), "no ground truth")


def test_missing_frame_names_its_line(tiny_tum: Path) -> None:
    folder = tiny_tum / FR1
    listed = (folder / "rgb.txt").read_text().splitlines()
    missing = listed[3 + 4].split()[1]  # the fifth frame, on line 8 after three comment lines
    (folder / missing).unlink()
    raises_one_line(lambda: tum.load_sequence(tiny_tum, FR1), f"{folder / 'rgb.txt'}:8:", repr(missing))


def test_frame_that_is_not_a_png(tiny_tum: Path) -> None:
    folder = tiny_tum / FR1
    first = folder / (folder / "rgb.txt").read_text().splitlines()[3].split()[1]
    first.write_bytes(b"not an image")
    raises_one_line(lambda: tum.load_sequence(tiny_tum, FR1), str(first), "not a PNG")


def test_no_frame_within_the_groundtruth(tmp_path: Path) -> None:
    folder = tmp_path / FR1
    write_frames(folder, 100.0 + np.arange(5) / 30)
    write_groundtruth(folder, 200.0 + np.arange(10) / 100)
    raises_one_line(
        lambda: tum.load_sequence(tmp_path, FR1),
        str(folder / "groundtruth.txt"),
        "no frame of",
        "within 0.02 s",
        "100.000..100.133",
        "200.000..200.090",
    )
