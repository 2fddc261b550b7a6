"""The synthetic town in the TUM RGB-D, EuRoC, TartanAir and MIMIR layouts, read back by lossvo's readers:
frame counts, times, sizes, cameras, ground-truth rates, and the geometry checked independently with ORB +
the essential matrix on the (distorted) frames against the readers' poses."""

from __future__ import annotations

import importlib
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from lossvo.data import euroc, sequence, tum
from lossvo.data.synthetic import cli as synthetic_cli
from lossvo.data.synthetic import layouts, platforms, writer

LAYOUTS = ("tum", "euroc", "tartanair", "mimir")
SCALE = 0.4
FRAMES = {"tum": 60, "euroc": 48, "tartanair": 40, "mimir": 48}
MIN_BASELINE = 0.15
"""Metres: frame pairs are this far apart at least (handheld frames move about 2 cm)."""


def read(root: Path, layout: str) -> sequence.Sequence:
    """Sequence 00 of a layout read by the layout's reader."""
    reader = importlib.import_module(f"lossvo.data.{layout}")
    return reader.load_sequence(root, layouts.sequence_name(layout, "00"))


@pytest.fixture(scope="module")
def roots(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """{layout: dataset root} of one small sequence (00) per layout."""
    return {
        layout: writer.generate(
            tmp_path_factory.mktemp(layout),
            ["00"],
            FRAMES[layout],
            layout=layout,
            scale=SCALE,
            progress=False,
        )
        for layout in LAYOUTS
    }


# --------------------------------------------------------------------------------------------------
# Layouts as the readers read them
# --------------------------------------------------------------------------------------------------


def test_sequence_names() -> None:
    names = {layout: layouts.sequence_name(layout, "07") for layout in layouts.LAYOUTS}
    assert names == {
        "kitti": "07",
        "tum": "rgbd_dataset_freiburg1_synthetic_07",
        "euroc": "synthetic_07",
        "tartanair": "synthetic/Easy/P007",
        "mimir": "SyntheticTown/auv0/track7",
    }


@pytest.mark.slow
@pytest.mark.parametrize("layout", LAYOUTS)
def test_reader_reads_what_was_rendered(roots: dict[str, Path], layout: str) -> None:
    seq = read(roots[layout], layout)
    spec = layouts.SPECS[layout]
    size = writer.frame_size(layout, scale=SCALE)
    K, distortion = layouts.camera(layout, size)
    assert len(seq.images) == FRAMES[layout] and seq.dropped == 0
    assert seq.size == size and cv2.imread(str(seq.images[0]), cv2.IMREAD_UNCHANGED).shape[:2] == size
    np.testing.assert_array_equal(seq.K, K)
    np.testing.assert_array_equal(seq.distortion, distortion)
    assert np.any(distortion != 0) == (layout in ("tum", "euroc"))
    period = np.diff(seq.times)
    jitter = 0.0035 if layout == "tum" else 1e-6
    assert np.abs(period - 1 / spec.rate_hz).max() <= 2 * jitter, period
    speed = np.linalg.norm(np.diff(seq.poses[:, :3, 3], axis=0), axis=1) / period
    low, high = {"tum": (0.15, 1.0), "euroc": (0.4, 1.6), "tartanair": (0.8, 2.2), "mimir": (0.15, 0.5)}[
        layout
    ]
    assert low <= speed.min() and speed.max() <= high, (speed.min(), speed.max())


@pytest.mark.slow
@pytest.mark.parametrize("layout", LAYOUTS)
def test_reader_poses_are_the_rendered_poses(roots: dict[str, Path], layout: str) -> None:
    """The poses each reader returns are the trajectory the frames were rendered from, at the frames'
    times: exactly (TartanAir), within the interpolation between 200/100 Hz rows (EuRoC, MIMIR), within
    the nearest 100 Hz stamp's motion (TUM associates, it does not interpolate)."""
    seq = read(roots[layout], layout)
    rendered = rendered_poses(layout)
    tolerance = {"tum": 5e-3, "euroc": 1e-5, "tartanair": 1e-7, "mimir": 1e-5}[layout]
    np.testing.assert_allclose(seq.poses, rendered, atol=tolerance)


def rendered_poses(layout: str) -> np.ndarray:
    """(N, 4, 4) T_w_c the frames of sequence 00 were rendered from, recomputed from the trajectory."""
    c = layouts.clock(layout, FRAMES[layout], layouts._streams(layout, "00", 0))
    route = layouts.sequence_route("00", _route_frames(layout), 0)
    motion = platforms.trajectory(route, layouts.SPECS[layout].platform, _motion_rng(layout))
    return motion.poses(c.seconds(c.frames)) @ layouts.mount(layout)


def _route_frames(layout: str) -> int:
    c = layouts.clock(layout, FRAMES[layout], layouts._streams(layout, "00", 0))
    return layouts.route_frames("00", _distance(layout, c), 0, writer.routes.DEFAULT_SPEC)


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["tum", "euroc"])
def test_undistorted_frames_are_pinhole_frames(roots: dict[str, Path], layout: str) -> None:
    """A frame undistorted with the reader's K and distortion (cv2.undistort) is the frame a pinhole camera
    renders from the same pose; the distorted frame as it is differs from it clearly more."""
    seq = read(roots[layout], layout)
    _, world, _ = layouts.scene("00", _route_frames(layout), 0)
    renderer = layouts.Renderer(world, seq.K, *seq.size)
    h, w = seq.size
    inner = (slice(h // 8, h - h // 8), slice(w // 8, w - w // 8))
    differences = []
    for k, T in list(enumerate(rendered_poses(layout)))[:: FRAMES[layout] // 4]:
        pinhole = cv2.cvtColor(renderer.render(T, np.random.default_rng(k)), cv2.COLOR_BGR2GRAY)
        frame = cv2.imread(str(seq.images[k]), cv2.IMREAD_GRAYSCALE)
        undistorted = cv2.undistort(frame, seq.K, seq.distortion)
        differences.append(
            [np.abs(a[inner].astype(float) - pinhole[inner]).mean() for a in (undistorted, frame)]
        )
    modelled, ignored = np.mean(differences, 0)
    print(f"{layout}: mean |undistorted - pinhole| {modelled:.2f}, |distorted - pinhole| {ignored:.2f}")
    assert modelled < 0.6 * ignored, (modelled, ignored)


def _motion_rng(layout: str) -> np.random.Generator:
    """The motion generator after the clock's draws, as render_sequence uses it."""
    rng = layouts._streams(layout, "00", 0)
    layouts.clock(layout, FRAMES[layout], rng)
    return rng


def _distance(layout: str, c: layouts.Clock) -> float:
    t = c.seconds(c.frames)
    t_end = float(c.seconds(c.groundtruth).max(initial=t[-1]))
    return platforms.max_distance(layouts.SPECS[layout].platform, t_end) + 5.0


@pytest.mark.slow
def test_groundtruth_at_its_own_rate_between_frames(roots: dict[str, Path]) -> None:
    frames_us = [int(line.split()[0].replace(".", "")) for line in _data(roots["tum"], "tum", "rgb.txt")]
    gt_us = [
        int(line.split()[0].replace(".", "")) * 100 for line in _data(roots["tum"], "tum", "groundtruth.txt")
    ]
    assert np.allclose(np.diff(gt_us), 10_000) and not set(frames_us) & set(gt_us)
    assert (roots["tum"] / layouts.sequence_name("tum", "00") / "rgb.txt").read_text().startswith("# ")
    name = layouts.sequence_name("euroc", "00")
    cam_ns, _ = euroc.read_camera_stamps(roots["euroc"] / name / "mav0/cam0/data.csv")
    gt_path = roots["euroc"] / name / "mav0/state_groundtruth_estimate0/data.csv"
    gt_ns, _ = euroc.read_groundtruth(gt_path)
    assert np.all(np.diff(gt_ns) == 5_000_000) and not set(cam_ns.tolist()) & set(gt_ns.tolist())
    assert all(len(line.split(",")) == 17 for line in gt_path.read_text().splitlines())
    frame = cv2.imread(
        str(roots["euroc"] / name / "mav0/cam0/data" / f"{cam_ns[0]}.png"), cv2.IMREAD_UNCHANGED
    )
    assert frame.ndim == 2 and frame.dtype == np.uint8


def _data(root: Path, layout: str, file: str) -> list[str]:
    text = (root / layouts.sequence_name(layout, "00") / file).read_text()
    return [line for line in text.splitlines() if line and not line.startswith("#")]


# --------------------------------------------------------------------------------------------------
# Geometry: ORB + essential matrix on the distorted frames
# --------------------------------------------------------------------------------------------------


def angle_deg(R: np.ndarray) -> float:
    """Rotation angle of a 3x3 rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def epipolar_px(p1: np.ndarray, p2: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> float:
    """Median distance (pixels) of the points p2 (P, 2) from the epipolar lines of p1 (P, 2) under the true
    motion x2 = R x1 + t (pinhole pixels of intrinsics K)."""
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    F = np.linalg.inv(K).T @ tx @ R @ np.linalg.inv(K)
    lines = np.c_[p1, np.ones(len(p1))] @ F.T
    distance = np.abs((np.c_[p2, np.ones(len(p2))] * lines).sum(1)) / np.linalg.norm(lines[:, :2], axis=1)
    return float(np.median(distance))


def pose_errors(
    images: list[np.ndarray], poses: np.ndarray, K: np.ndarray, distortion: np.ndarray, pairs: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation and translation-direction errors (deg) of ORB + 5-point per frame pair (P, 2) of grey
    images (H, W) uint8, against poses (N, 4, 4) T_w_c, and the median epipolar distance (px) of the
    pair's matches under the true motion; keypoints undistorted with K (3, 3) and distortion (D,) first."""
    orb = cv2.ORB_create(nfeatures=2000, edgeThreshold=15, patchSize=15)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    features = [orb.detectAndCompute(img, None) for img in images]
    rot, trans, epipolar = [], [], []
    for i, j in pairs:
        (kp1, des1), (kp2, des2) = features[i], features[j]
        matches = matcher.match(des1, des2)
        p1 = np.array([kp1[m.queryIdx].pt for m in matches], np.float64)
        p2 = np.array([kp2[m.trainIdx].pt for m in matches], np.float64)
        p1, p2 = (cv2.undistortPoints(p[:, None], K, distortion, P=K)[:, 0] for p in (p1, p2))
        E, mask = cv2.findEssentialMat(p1, p2, K, method=cv2.RANSAC, prob=0.999, threshold=0.5)
        _, R, t, _ = cv2.recoverPose(E[:3], p1, p2, K, mask=mask)
        T_rel = np.linalg.inv(poses[i]) @ poses[j]
        R_true, t_true = T_rel[:3, :3].T, -T_rel[:3, :3].T @ T_rel[:3, 3]
        rot.append(angle_deg(R @ R_true.T))
        cos = t.ravel() @ t_true / (np.linalg.norm(t) * np.linalg.norm(t_true))
        trans.append(float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))))
        epipolar.append(epipolar_px(p1, p2, K, R_true, t_true))
    return np.array(rot), np.array(trans), np.array(epipolar)


def frame_pairs(poses: np.ndarray) -> np.ndarray:
    """(P, 2) pairs (k, k + s) with the smallest step s that moves every pair at least MIN_BASELINE."""
    for s in range(1, len(poses)):
        baseline = np.linalg.norm(poses[s:, :3, 3] - poses[:-s, :3, 3], axis=1)
        if baseline.min() >= MIN_BASELINE:
            return np.stack([np.arange(len(poses) - s), np.arange(s, len(poses))], 1)
    raise AssertionError("the sequence never moves MIN_BASELINE")


def long_pairs(n: int) -> np.ndarray:
    """(n - n // 2, 2) pairs (k, k + n // 2): the largest rotations a sequence has, where a lens model
    matters most."""
    return np.stack([np.arange(n - n // 2), np.arange(n // 2, n)], 1)


def geometry_medians(
    seq: sequence.Sequence, distortion: np.ndarray, pairs: np.ndarray | None = None
) -> tuple[float, float, float, int]:
    """Median rotation error (pixels: radians x focal length), median direction error x baseline (deg m),
    median epipolar distance (px) under the reader's poses, pair count; pairs (P, 2) default
    :func:`frame_pairs`."""
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in seq.images]
    assert seq.poses is not None
    pairs = frame_pairs(seq.poses) if pairs is None else pairs
    rot, trans, epipolar = pose_errors(images, seq.poses, seq.K, distortion, pairs)
    baseline = np.linalg.norm(seq.poses[pairs[:, 1], :3, 3] - seq.poses[pairs[:, 0], :3, 3], axis=1)
    rot_px = np.radians(np.median(rot)) * math.sqrt(seq.K[0, 0] * seq.K[1, 1])
    return rot_px, float(np.median(trans * baseline)), float(np.median(epipolar)), len(pairs)


def report(label: str, medians: tuple[float, float, float, int]) -> str:
    rot, direction, epipolar, n = medians
    return (
        f"{label}: {n} pairs, median rotation {rot:.2f} px, direction x baseline {direction:.2f} deg m, "
        + (f"epipolar distance {epipolar:.2f} px")
    )


@pytest.mark.slow
@pytest.mark.parametrize("layout", LAYOUTS)
def test_orb_essential_matrix_recovers_the_readers_poses(roots: dict[str, Path], layout: str) -> None:
    """Bounds: median rotation error 1.5 pixels (KITTI's 0.3 degree at its 296-pixel focal length, see
    tests/test_synthetic.py), direction x baseline 5 deg m, matches 0.5 pixel from their true epipolar
    lines; with the lens distortion ignored (EuRoC), on pairs half the sequence apart (rotations of
    several degrees: radial distortion bends rotations, while it moves points along the lines of a forward
    motion), the rotation errors at least double."""
    seq = read(roots[layout], layout)
    medians = geometry_medians(seq, seq.distortion)
    print(report(layout, medians))
    rot, direction, epipolar, n = medians
    assert n >= 20 and rot <= 1.5 and direction <= 5.0 and epipolar <= 0.5, report(layout, medians)
    if layout == "euroc":  # fr1's lens is a nearly uniform 2-6 % magnification: ORB + E hardly sees it
        pairs = long_pairs(len(seq.images))
        modelled, ignored = (geometry_medians(seq, d, pairs) for d in (seq.distortion, np.zeros(5)))
        print(report(f"{layout}, long pairs", modelled))
        print(report(f"{layout}, long pairs, distortion ignored", ignored))
        assert modelled[0] <= 1.5 and ignored[0] > 2 * modelled[0], report(layout, ignored)


# --------------------------------------------------------------------------------------------------
# Command line and determinism
# --------------------------------------------------------------------------------------------------


def test_cli_writes_a_layout(tmp_path: Path) -> None:
    argv = ["--out", str(tmp_path), "--layout", "tartanair", "--scale", "0.2", "--frames", "3", "--quiet"]
    assert synthetic_cli.main([*argv, "--sequences", "05"]) == 0
    seq = importlib.import_module("lossvo.data.tartanair").load_sequence(tmp_path, "synthetic/Easy/P005")
    assert len(seq.images) == 3 and seq.size == (96, 128)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["--layout", "colmap"],
            "invalid choice: 'colmap' (choose from 'kitti', 'tum', 'euroc', 'tartanair', 'mimir')",
        ),
        (["--layout", "tum", "--scale", "0"], "--scale: must be a number > 0, got 0.0"),
        (
            ["--layout", "tum", "--scale", "0.01"],
            "--scale: 0.01 gives 5x6 pixels for the tum layout's 480x640",
        ),
    ],
)
def test_cli_bad_values_exit_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture, args: list[str], message: str
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        synthetic_cli.main(["--out", str(tmp_path / "d"), *args])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "d").exists()


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_same_seed_same_bytes(tmp_path: Path) -> None:
    params = {"sequences": ["02"], "frames": 4, "layout": "euroc", "scale": 0.2, "progress": False}
    a, b = writer.generate(tmp_path / "a", **params), writer.generate(tmp_path / "b", **params)
    assert tree_bytes(a) == tree_bytes(b)
    c = writer.generate(tmp_path / "c", **params, seed=1)
    assert tree_bytes(c) != tree_bytes(a)


@pytest.mark.slow
def test_ensure_dataset_reuses_complete_sequences(tmp_path: Path) -> None:
    params = {"sequences": ["03"], "frames": 3, "layout": "mimir", "scale": 0.2, "progress": False}
    root = writer.ensure_dataset(tmp_path, **params)
    image = next((root / layouts.sequence_name("mimir", "03")).rglob("*.png"))
    stamp = image.stat().st_mtime_ns
    writer.ensure_dataset(tmp_path, **params)
    assert image.stat().st_mtime_ns == stamp
    writer.ensure_dataset(tmp_path, **{**params, "scale": 0.25})  # another size: rendered again
    assert cv2.imread(str(image)).shape[:2] == writer.frame_size("mimir", scale=0.25)


def test_tum_stamps_never_fall_on_the_groundtruth() -> None:
    c = layouts.clock("tum", 500, np.random.default_rng(0))
    assert not np.isin(c.frames, c.groundtruth).any() and np.all(np.diff(c.frames) > 0)
    assert c.groundtruth[0] < c.frames[0] - 50_000 and c.groundtruth[-1] > c.frames[-1] + 50_000
    assert tum.associate(c.frames * 1e-6, c.groundtruth * 1e-6)[0].size == 500
    assert math.isclose(c.unit, 1e-6)
