"""The synthetic KITTI-layout dataset: geometry checked independently with ORB + the essential matrix,
file formats, determinism, motion statistics, the command line and ensure_dataset's caching.

Poses and calibration are read here with a few lines of numpy on purpose (not with lossvo.data.kitti),
so that the check is independent of the project's own readers.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from lossvo.console import UserError
from lossvo.data import motion, synthetic
from lossvo.data.synthetic import cli as synthetic_cli
from lossvo.data.synthetic import routes, writer
from lossvo.data.synthetic.manifest import RENDERING

GEOMETRY_SEQUENCES = ("00", "07", "11")
GEOMETRY_FRAMES = 40


# --------------------------------------------------------------------------------------------------
# Independent readers
# --------------------------------------------------------------------------------------------------


def read_poses(path: Path) -> np.ndarray:
    """KITTI poses file -> (N, 4, 4) float64 T_w_c."""
    rows = np.array([[float(v) for v in line.split()] for line in path.read_text().splitlines()])
    assert rows.shape[1] == 12, f"{path}: expected 12 floats a line"
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3] = rows.reshape(-1, 3, 4)
    return poses


def read_calib(path: Path) -> dict[str, np.ndarray]:
    """KITTI calib.txt -> {name: (12,) float64}."""
    calib = {}
    for line in path.read_text().splitlines():
        name, values = line.split(":", 1)
        calib[name] = np.array([float(v) for v in values.split()])
    return calib


def angle_deg(R: np.ndarray) -> float:
    """Rotation angle of a 3x3 rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


# --------------------------------------------------------------------------------------------------
# Fixtures
# --------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small dataset at the default resolution: 3 sequences of 40 frames."""
    out = tmp_path_factory.mktemp("synthetic")
    return synthetic.generate(out, GEOMETRY_SEQUENCES, GEOMETRY_FRAMES, progress=False)


# --------------------------------------------------------------------------------------------------
# 1. Geometry: ORB + essential matrix recover the written relative poses
# --------------------------------------------------------------------------------------------------


def relative_pose_errors(root: Path, sequence: str) -> tuple[np.ndarray, np.ndarray]:
    """Per consecutive pair: rotation error (deg) and translation-direction error (deg) of ORB + 5-point."""
    K = read_calib(root / "sequences" / sequence / "calib.txt")["P2"].reshape(3, 4)[:, :3]
    poses = read_poses(root / "poses" / f"{sequence}.txt")
    files = sorted((root / "sequences" / sequence / "image_2").glob("*.png"))
    return pose_errors([cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files], poses, K)


def pose_errors(images: list[np.ndarray], poses: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation-direction errors (deg) per consecutive pair of grey images (H, W) uint8
    against the poses (N, 4, 4) T_w_c, with intrinsics K (3, 3)."""
    # Frames DEFAULT_HEIGHT (160) pixels high: a 15-pixel border and patch instead of ORB's default 31 keep
    # most of the image.
    orb = cv2.ORB_create(nfeatures=2000, edgeThreshold=15, patchSize=15)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    features = [orb.detectAndCompute(img, None) for img in images]
    rot, trans = [], []
    for k in range(len(images) - 1):
        (kp1, des1), (kp2, des2) = features[k], features[k + 1]
        matches = matcher.match(des1, des2)
        p1 = np.array([kp1[m.queryIdx].pt for m in matches], np.float64)
        p2 = np.array([kp2[m.trainIdx].pt for m in matches], np.float64)
        E, mask = cv2.findEssentialMat(p1, p2, K, method=cv2.RANSAC, prob=0.999, threshold=0.5)
        _, R, t, _ = cv2.recoverPose(E[:3], p1, p2, K, mask=mask)
        T_rel = np.linalg.inv(poses[k]) @ poses[k + 1]  # frame k+1 seen from frame k
        R_true = T_rel[:3, :3].T  # recoverPose maps frame-k points to frame k+1: x2 = R x1 + t
        t_true = -T_rel[:3, :3].T @ T_rel[:3, 3]
        rot.append(angle_deg(R @ R_true.T))
        cos = t.ravel() @ t_true / (np.linalg.norm(t) * np.linalg.norm(t_true))
        trans.append(float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))))
    return np.array(rot), np.array(trans)


MIN_BASELINE = 0.15
"""Metres: pairs that move less are not checked (standing pairs have no essential matrix)."""


def check_geometry(label: str, rot: np.ndarray, trans: np.ndarray, poses: np.ndarray) -> None:
    """Median rotation error <= 0.3 deg and median direction error x baseline <= 5 deg m (5 deg at 1 m:
    the direction of a shorter step is less well determined by whole-pixel keypoints) over the pairs
    that move at least MIN_BASELINE."""
    step = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    moving = step >= MIN_BASELINE
    rot_med, dir_med = np.median(rot[moving]), np.median(trans[moving] * step[moving])
    report = f"{label}: median errors: rotation {rot_med:.3f} deg, direction x baseline {dir_med:.2f} deg m"
    print(report)
    assert moving.sum() >= 10, report
    assert rot_med <= 0.3 and dir_med <= 5.0, report


@pytest.mark.slow
@pytest.mark.parametrize("sequence", GEOMETRY_SEQUENCES)
def test_orb_essential_matrix_recovers_written_poses(dataset: Path, sequence: str) -> None:
    rot, trans = relative_pose_errors(dataset, sequence)
    assert len(rot) == GEOMETRY_FRAMES - 1
    check_geometry(sequence, rot, trans, read_poses(dataset / "poses" / f"{sequence}.txt"))


# --------------------------------------------------------------------------------------------------
# 2. Layout and formats
# --------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_layout_and_formats(dataset: Path) -> None:
    h, w = synthetic.DEFAULT_HEIGHT, synthetic.DEFAULT_WIDTH
    for seq in GEOMETRY_SEQUENCES:
        seq_dir = dataset / "sequences" / seq
        files = sorted((seq_dir / "image_2").glob("*.png"))
        assert [f.name for f in files] == [f"{k:06d}.png" for k in range(GEOMETRY_FRAMES)]

        lines = (dataset / "poses" / f"{seq}.txt").read_text().splitlines()
        assert len(lines) == GEOMETRY_FRAMES and all(len(line.split()) == 12 for line in lines)
        poses = read_poses(dataset / "poses" / f"{seq}.txt")
        np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-12)
        R = poses[:, :3, :3]
        np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-8)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-8)

        times = [float(v) for v in (seq_dir / "times.txt").read_text().split()]
        np.testing.assert_allclose(times, np.arange(GEOMETRY_FRAMES) * 0.1, atol=1e-9)
        assert (seq_dir / "times.txt").read_text().startswith("0.000000e+00\n1.000000e-01\n")

        calib = read_calib(seq_dir / "calib.txt")
        assert list(calib) == ["P0", "P1", "P2", "P3", "Tr"]
        assert all(v.shape == (12,) for v in calib.values())
        P2 = calib["P2"].reshape(3, 4)
        np.testing.assert_allclose(P2[:, 3], 0.0)
        np.testing.assert_allclose(P2[:, :3], synthetic.intrinsics(h, w))
        assert abs(P2[0, 0] - 718.856 * w / 1241) < 1e-6 and abs(P2[1, 1] - 718.856 * h / 376) < 1e-6

        for f in files[:: GEOMETRY_FRAMES // 4]:
            img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            assert img.shape == (h, w, 3) and img.dtype == np.uint8
            assert img.std() > 20  # textured, not constant
            assert np.abs(img[..., 0].astype(int) - img[..., 2]).mean() > 2  # colour, not grey

    manifest = json.loads((dataset / synthetic.MANIFEST).read_text())
    assert manifest["height"] == h and manifest["width"] == w and manifest["seed"] == 0
    assert manifest["frames"] == dict.fromkeys(GEOMETRY_SEQUENCES, GEOMETRY_FRAMES)
    assert not list(dataset.glob(".tmp*"))


# --------------------------------------------------------------------------------------------------
# 3. Determinism
# --------------------------------------------------------------------------------------------------


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_small_datasets_render_in_this_process() -> None:
    assert writer._worker_count(3, None, writer.PARALLEL_PIXELS - 1) == 1
    assert writer._worker_count(3, None, writer.PARALLEL_PIXELS) == min(3, os.cpu_count() or 1)
    assert writer._worker_count(3, 2, 100) == 2  # an explicit count wins
    assert writer._worker_count(1, 2, writer.PARALLEL_PIXELS) == 1  # at most one process a sequence


@pytest.mark.slow
def test_same_seed_same_bytes_and_sequences_differ(tmp_path: Path, dataset: Path) -> None:
    a = synthetic.generate(tmp_path / "a", ["03"], 4, progress=False, workers=1)
    b = synthetic.generate(tmp_path / "b", ["04", "03"], 4, progress=False, workers=2)  # in a worker process
    assert tree_bytes(a / "sequences/03") == tree_bytes(b / "sequences/03")
    assert (a / "poses/03.txt").read_bytes() == (b / "poses/03.txt").read_bytes()
    c = synthetic.generate(tmp_path / "c", ["03"], 4, seed=1, progress=False, workers=1)
    assert (c / "sequences/03/image_2/000000.png").read_bytes() != (
        a / "sequences/03/image_2/000000.png"
    ).read_bytes()

    first = [cv2.imread(str(dataset / f"sequences/{s}/image_2/000000.png")) for s in GEOMETRY_SEQUENCES]
    assert all(np.abs(x.astype(int) - y).mean() > 10 for x, y in itertools.pairwise(first))
    routes = [read_poses(dataset / "poses" / f"{s}.txt")[:, :3, 3] for s in GEOMETRY_SEQUENCES]
    assert all(np.abs(x - y).max() > 1.0 for x, y in itertools.pairwise(routes))


# --------------------------------------------------------------------------------------------------
# 4. Motion statistics
# --------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_written_poses_are_the_sequences_routes(dataset: Path) -> None:
    for seq in GEOMETRY_SEQUENCES:
        written = read_poses(dataset / "poses" / f"{seq}.txt")
        np.testing.assert_allclose(written, synthetic.sequence_route(seq, GEOMETRY_FRAMES), atol=1e-6)
    for seq, n in synthetic.DEFAULT_FRAMES.items():  # every default route is a plausible drive
        poses = synthetic.sequence_route(seq, n)
        steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
        assert 0.2 <= steps.mean() <= 1.45 and steps.max() <= 1.6, (seq, steps.mean())
        tilt = np.degrees(np.arccos(np.clip(poses[:, 1, 1], -1, 1)))  # camera y axis vs world down
        assert tilt.max() < 5.2


@functools.cache  # rendered once per family for the tests below (they only read the arrays)
def busiest_frames(family: str) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Grey frames (H, W) of 31 poses around a route's busiest rotation in one family, the poses
    (31, 4, 4) and the intrinsics (3, 3). Slow families are rendered on frames further apart (about
    0.6 m): any two rendered frames must agree with their relative pose, and a longer baseline
    determines it better."""
    rng = np.random.default_rng(7)
    poses = routes.make_route(rng, 600, {family: 1.0})
    speed, rotation = motion.frame_motion(poses)
    busiest = int(np.convolve(rotation, np.ones(30), mode="valid").argmax())
    step = max(1, math.ceil(0.6 / np.median(speed[busiest : busiest + 30])))
    start = min(busiest, len(poses) - 30 * step - 1)
    world = synthetic.build_world(rng, poses)
    h, w = synthetic.DEFAULT_HEIGHT, synthetic.DEFAULT_WIDTH
    K = synthetic.intrinsics(h, w)
    renderer = synthetic.Renderer(world, K, h, w)
    window = poses[start : start + 30 * step + 1 : step]
    return [cv2.cvtColor(renderer.render(T, rng), cv2.COLOR_BGR2GRAY) for T in window], window, K


@pytest.mark.slow
@pytest.mark.parametrize("family", list(routes.FAMILIES))
def test_orb_essential_matrix_recovers_every_route_familys_poses(family: str) -> None:
    """The render-geometry check on 30 frame pairs around each family's busiest rotation."""
    images, poses, K = busiest_frames(family)
    rot, trans = pose_errors(images, poses, K)
    check_geometry(family, rot, trans, poses)


@pytest.mark.slow
def test_mirrored_frames_move_as_the_mirrored_poses() -> None:
    """What the Mirror transform trains on: frames flipped left to right, seen through the mirrored principal
    point (cx -> W - 1 - cx), move as S @ T_w_c @ S with S = diag(-1, 1, 1, 1); the unmirrored poses, which
    turn the other way, do not fit them."""
    images, poses, K = busiest_frames("town")
    mirrored = [cv2.flip(image, 1) for image in images]
    K = K.copy()
    K[0, 2] = images[0].shape[1] - 1 - K[0, 2]
    S = np.diag([-1.0, 1.0, 1.0, 1.0])
    rot, trans = pose_errors(mirrored, S @ poses @ S, K)
    check_geometry("town, mirrored", rot, trans, S @ poses @ S)
    rot_unmirrored, _ = pose_errors(mirrored, poses, K)
    assert np.median(rot_unmirrored) > 3 * max(np.median(rot), 0.1)


# --------------------------------------------------------------------------------------------------
# 5. Command line
# --------------------------------------------------------------------------------------------------
# Its bad values: rows of docs/bad-input.md (tests/test_bad_input.py).


def test_cli_writes_a_dataset(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """In process (tests/test_bad_input.py runs the real command line)."""
    assert synthetic_cli.main(["--out", str(tmp_path / "d"), "--sequences", "00", "--frames", "5"]) == 0
    err = capsys.readouterr().err
    size = sum(p.stat().st_size for p in (tmp_path / "d").rglob("*") if p.is_file() and p.suffix != ".json")
    assert f"wrote {tmp_path / 'd'} in " in err and f", {size / 1e6:.0f} MB" in err
    assert len(list((tmp_path / "d/sequences/00/image_2").glob("*.png"))) == 5
    assert len((tmp_path / "d/poses/00.txt").read_text().splitlines()) == 5
    assert (tmp_path / "d" / synthetic.MANIFEST).is_file()


# --------------------------------------------------------------------------------------------------
# 6. ensure_dataset and interrupted runs
# --------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_ensure_dataset_generates_once_and_again_on_new_parameters(tmp_path: Path) -> None:
    params = {"sequences": ["04"], "frames": 3, "progress": False, "workers": 1}
    root = synthetic.ensure_dataset(tmp_path, **params)
    manifest, image = root / synthetic.MANIFEST, root / "sequences/04/image_2/000000.png"
    stamps = (manifest.stat().st_mtime_ns, image.stat().st_mtime_ns)

    assert synthetic.ensure_dataset(tmp_path, **params) == root
    assert (manifest.stat().st_mtime_ns, image.stat().st_mtime_ns) == stamps

    synthetic.ensure_dataset(tmp_path, **{**params, "frames": 4})
    assert len(list((root / "sequences/04/image_2").glob("*.png"))) == 4
    assert json.loads(manifest.read_text())["frames"] == {"04": 4}
    assert image.stat().st_mtime_ns != stamps[1]

    synthetic.ensure_dataset(tmp_path, **{**params, "frames": 4, "height": 64, "width": 208})
    assert cv2.imread(str(image)).shape == (64, 208, 3)


def test_interrupted_run_leaves_no_complete_looking_sequence(tmp_path: Path, monkeypatch) -> None:
    calls = []

    def failing_render(self, T_w_c, rng):
        calls.append(1)
        if len(calls) > 2:
            raise KeyboardInterrupt
        return np.zeros((*self.size, 3), np.uint8)

    monkeypatch.setattr(synthetic.Renderer, "render", failing_render)
    with pytest.raises(KeyboardInterrupt):
        synthetic.generate(tmp_path, ["05"], 4, progress=False, workers=1)
    assert (
        not (tmp_path / synthetic.MANIFEST).exists() and (tmp_path / RENDERING).exists()
    )  # ours, unfinished
    assert not (tmp_path / "sequences/05").exists() and not (tmp_path / "poses/05.txt").exists()
    assert not list(tmp_path.glob(".tmp*"))
    monkeypatch.undo()

    synthetic.ensure_dataset(tmp_path, ["05"], 3, progress=False, workers=1)
    assert len(list((tmp_path / "sequences/05/image_2").glob("*.png"))) == 3


def test_a_folder_of_someone_elses_data_is_refused_and_left_as_it_was(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A KITTI tree lossvo did not render (no manifest): one line, exit status 2, every file as it was. An
    empty folder, or an interrupted render of lossvo's, is written into."""
    kitti = tmp_path / "K"
    files = {"poses/00.txt": "1 0 0 0 0 1 0 0 0 0 1 0\n", "sequences/00/image_2/000000.png": "not a png"}
    for name, text in files.items():
        (kitti / name).parent.mkdir(parents=True, exist_ok=True)
        (kitti / name).write_text(text)
    before = {p: p.read_bytes() for p in kitti.rglob("*") if p.is_file()}
    argv = ["--out", str(kitti), "--sequences", "00", "--scale", "0.25", "--frames", "10"]
    assert synthetic_cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err == (
        f"error: {kitti}: holds files that lossvo did not render (no {synthetic.MANIFEST}): give a new or "
        "empty folder for the synthetic dataset; lossvo does not write into data it did not make\n"
    )
    assert {p: p.read_bytes() for p in kitti.rglob("*") if p.is_file()} == before
    (tmp_path / "empty").mkdir()
    synthetic.generate(tmp_path / "empty", ["04"], 3, progress=False, workers=1)
    assert (
        not (tmp_path / "empty" / RENDERING).exists() and (tmp_path / "empty" / synthetic.MANIFEST).is_file()
    )


def test_bad_parameters_raise_value_errors(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="two-digit"):
        synthetic.generate(tmp_path, ["7"], 3)
    with pytest.raises(UserError, match="frames"):
        synthetic.generate(tmp_path, ["07"], 1)
    with pytest.raises(UserError, match="height"):
        synthetic.generate(tmp_path, ["07"], 3, height=8)
    assert not list(tmp_path.iterdir())
