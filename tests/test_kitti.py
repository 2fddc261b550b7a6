"""lossvo.data.kitti: pose files (round trips with evo), calib, sequences, and every bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from evo.core.trajectory import PosePath3D
from evo.tools import file_interface

from lossvo import geometry
from lossvo.data import kitti, pose_files
from lossvo.data.sequence import DatasetFormatError


def random_trajectory(n: int = 50, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) float64 camera-to-world poses of a random smooth-ish trajectory."""
    gen = torch.Generator().manual_seed(seed)
    steps = geometry.se3_exp(0.2 * torch.randn(n - 1, 6, generator=gen, dtype=torch.float64))
    poses = [torch.eye(4, dtype=torch.float64)]
    for T in steps:  # building test data, not hot code
        poses.append(poses[-1] @ T)
    return torch.stack(poses).numpy()


def test_reads_what_evo_writes(tmp_path: Path) -> None:
    poses = random_trajectory()
    path = tmp_path / "00.txt"
    file_interface.write_kitti_poses_file(str(path), PosePath3D(poses_se3=list(poses)))
    np.testing.assert_allclose(kitti.read_poses(path), poses, atol=1e-12, rtol=0)


def test_evo_reads_what_lossvo_writes(tmp_path: Path) -> None:
    poses = random_trajectory(seed=1)
    path = tmp_path / "sub" / "01.txt"
    pose_files.write_poses(path, poses)
    traj = file_interface.read_kitti_poses_file(str(path))
    np.testing.assert_allclose(np.stack(traj.poses_se3), poses, atol=1e-8, rtol=0)
    np.testing.assert_allclose(kitti.read_poses(path), poses, atol=1e-8, rtol=0)


def test_relative_targets_convention() -> None:
    poses = random_trajectory()
    rel = kitti.relative_targets(poses)
    np.testing.assert_allclose(rel, np.linalg.inv(poses[:-1]) @ poses[1:], atol=1e-12)
    assert rel.dtype == np.float64


def test_sequence_metadata(tiny_kitti: Path) -> None:
    seq = kitti.load_sequence(tiny_kitti, "01")
    assert len(seq.images) == 10 and seq.poses.shape == (10, 4, 4)
    assert seq.targets.shape == (9, 4, 4)
    K = seq.K
    assert K.shape == (3, 3) and K[0, 0] > 0 and K[2, 2] == 1.0
    times = kitti.read_times(tiny_kitti / "sequences" / "01" / "times.txt")
    np.testing.assert_allclose(np.diff(times), 0.1, atol=1e-9)
    np.testing.assert_array_equal(seq.times, times)
    assert seq.size == (64, 208) and not seq.distortion.any()


def test_root_may_hold_dataset(tiny_kitti: Path, tmp_path: Path) -> None:
    shutil.copytree(tiny_kitti, tmp_path / "dataset")
    assert kitti.find_root(tmp_path) == tmp_path / "dataset"
    assert len(kitti.load_sequence(tmp_path, "00").images) == 10


def test_sequence_without_poses_is_for_inference_only(kitti_copy: Path) -> None:
    (kitti_copy / "poses" / "02.txt").unlink()
    with pytest.raises(kitti.KittiFormatError, match=r"02\.txt: no pose file for sequence 02"):
        kitti.load_sequence(kitti_copy, "02")
    seq = kitti.load_sequence(kitti_copy, "02", require_poses=False)
    assert seq.poses is None and len(seq.images) == 10
    with pytest.raises(DatasetFormatError, match="usable for inference only"):
        _ = seq.targets


# -- bad input: one clear error naming the path (and line) ------------------------------------------


def test_missing_root(tmp_path: Path) -> None:
    with pytest.raises(kitti.KittiFormatError, match=r"nowhere: dataset root does not exist"):
        kitti.find_root(tmp_path / "nowhere")


def test_root_without_sequences(tmp_path: Path) -> None:
    with pytest.raises(
        kitti.KittiFormatError, match=r"not a KITTI odometry root: expected .*sequences/NN/image_2"
    ):
        kitti.find_root(tmp_path)


def test_missing_sequence(tiny_kitti: Path) -> None:
    with pytest.raises(
        kitti.KittiFormatError, match=r"sequences/07: sequence '07' not found \(available: 00, 01, 02\)"
    ):
        kitti.load_sequence(tiny_kitti, "07")


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("1 0 0 0 0 1 0 0 0 0 1", r"00\.txt:3: expected 12 numbers, got 11"),
        ("1 0 0 0 0 1 0 0 0 0 1 x", r"00\.txt:3: expected 12 numbers, got 'x'"),
        ("1 0 0 0 0 1 0 0 0 0 1 nan", r"00\.txt:3: expected finite numbers"),
        ("1 0 0 0 0 2 0 0 0 0 1 0", r"00\.txt:3: rotation block is not a rotation"),
        ("1 0 0 0 0 1 0 0 0 0 -1 0", r"00\.txt:3: rotation block is not a rotation .*det = -1"),
    ],
)
def test_bad_pose_line_is_named(kitti_copy: Path, line: str, message: str) -> None:
    path = kitti_copy / "poses" / "00.txt"
    lines = path.read_text().splitlines()
    lines[2] = line
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(kitti.KittiFormatError, match=message):
        kitti.load_sequence(kitti_copy, "00")


def test_pose_count_must_match_frames(kitti_copy: Path) -> None:
    path = kitti_copy / "poses" / "00.txt"
    path.write_text("\n".join(path.read_text().splitlines()[:-1]) + "\n")
    with pytest.raises(kitti.KittiFormatError, match=r"00\.txt: 9 poses but 10 frames in .*image_2"):
        kitti.load_sequence(kitti_copy, "00")


def test_calib_without_p2(kitti_copy: Path) -> None:
    path = kitti_copy / "sequences" / "00" / "calib.txt"
    path.write_text("\n".join(s for s in path.read_text().splitlines() if not s.startswith("P2")) + "\n")
    with pytest.raises(kitti.KittiFormatError, match=r"calib\.txt: no P2"):
        kitti.load_sequence(kitti_copy, "00")


def test_malformed_calib_line(kitti_copy: Path) -> None:
    path = kitti_copy / "sequences" / "00" / "calib.txt"
    path.write_text("P0 1 2 3\n" + path.read_text())
    with pytest.raises(kitti.KittiFormatError, match=r"calib\.txt:1: expected 'KEY: 12 numbers'"):
        kitti.read_calib(path)


def test_truncated_png(kitti_copy: Path) -> None:
    path = kitti_copy / "sequences" / "00" / "image_2" / "000004.png"
    path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(kitti.KittiFormatError, match=r"000004\.png: not a complete PNG file"):
        kitti.check_png(path)


def test_no_frames(kitti_copy: Path) -> None:
    for p in (kitti_copy / "sequences" / "01" / "image_2").glob("*.png"):
        p.unlink()
    with pytest.raises(kitti.KittiFormatError, match=r"01/image_2: expected PNG frames"):
        kitti.load_sequence(kitti_copy, "01")


def test_times_txt_is_required_and_matches_the_frames(kitti_copy: Path) -> None:
    path = kitti_copy / "sequences" / "00" / "times.txt"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(kitti.KittiFormatError, match=r"times\.txt: 9 timestamps but 10 frames"):
        kitti.load_sequence(kitti_copy, "00")
    path.unlink()
    with pytest.raises(kitti.KittiFormatError, match=r"times\.txt: cannot read timestamps"):
        kitti.load_sequence(kitti_copy, "00")


def test_a_tum_trajectory_read_as_kitti_poses_says_so(tmp_path: Path) -> None:
    path = tmp_path / "traj.txt"
    path.write_text("1.0 0 0 0 0 0 0 1\n1.1 0 0 1 0 0 0 1\n")
    expected = (
        r"traj\.txt:1: expected 12 numbers \(a KITTI pose file\), got 8: a TUM trajectory .* Name it \.tum"
    )
    with pytest.raises(kitti.KittiFormatError, match=expected):
        kitti.read_poses(path)
