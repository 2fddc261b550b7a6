"""The baselines on hand-written KITTI-layout sequences (noise frames, known poses): the own-mean-motion
oracle equals an independent computation, its scores equal evo's, and it is exact on constant-velocity
motion; the zero-motion and mean-motion scores equal evo's; the sequences and the training split come from
the recorded data; cache files that lack a baseline, or whose recorded data, training flow or flow
settings differ, are recomputed (the flow baseline itself: tests/test_flow_baselines.py)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.core.trajectory import PosePath3D

from lossvo.console import UserError
from lossvo.data.sequence import Sequence
from lossvo.evaluation import baselines
from lossvo.evaluation.job_folder import DataRecord, Scores

FRAMES, HEIGHT, WIDTH = 8, 64, 96
P2 = np.array([[60.0, 0, WIDTH / 2, 0], [0, 60.0, HEIGHT / 2, 0], [0, 0, 1, 0]])


def step(yaw: float, forward: float, right: float = 0.0) -> np.ndarray:
    """(4, 4) relative pose: a rotation by ``yaw`` (rad) about the camera's y axis, then a translation
    (m) of ``right`` along x and ``forward`` along z."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.eye(4)
    out[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    out[:3, 3] = [right, 0.0, forward]
    return out


def chain(steps: list[np.ndarray]) -> np.ndarray:
    """(len(steps) + 1, 4, 4) poses from the identity, ``T_w_{k+1} = T_w_k @ T_k``."""
    poses = [np.eye(4)]
    for t in steps:
        poses.append(poses[-1] @ t)
    return np.stack(poses)


def write_sequence(root: Path, name: str, poses: np.ndarray, seed: int) -> Sequence:
    """Noise frames, calib.txt and poses/<name>.txt in the KITTI layout under ``root``."""
    folder = root / "sequences" / name / "image_2"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    images = []
    for i in range(len(poses)):
        images.append(folder / f"{i:06d}.png")
        cv2.imwrite(str(images[-1]), rng.integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8))
    numbers = " ".join(f"{v:.6f}" for v in P2.ravel())
    (folder.parent / "calib.txt").write_text("".join(f"P{i}: {numbers}\n" for i in range(4)))
    times = 0.1 * np.arange(len(poses))
    np.savetxt(folder.parent / "times.txt", times)
    (root / "poses").mkdir(exist_ok=True)
    np.savetxt(root / "poses" / f"{name}.txt", poses[:, :3, :].reshape(len(poses), 12))
    return Sequence(name, images, times, poses, P2[:, :3].copy(), np.zeros(5), (HEIGHT, WIDTH))


def varied_poses(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return chain([step(rng.uniform(-0.05, 0.05), rng.uniform(0.2, 1.2), rng.uniform(-0.1, 0.1))
                  for _ in range(FRAMES - 1)])  # fmt: skip


def evo_rmse(gt: np.ndarray, est: np.ndarray, kind: str, relation: str) -> float:
    """evo's APE or RPE (delta 1 frame, no alignment) RMSE of ``est`` (N, 4, 4) against ``gt``:
    ``relation`` "trans" (m, translation part) or "rot_rad" (rotation angle)."""
    pose_relation = {"trans": evo_metrics.PoseRelation.translation_part,
                     "rot_rad": evo_metrics.PoseRelation.rotation_angle_rad}[relation]  # fmt: skip
    metric = evo_metrics.APE(pose_relation) if kind == "ape" else evo_metrics.RPE(pose_relation, delta=1)
    metric.process_data((PosePath3D(poses_se3=list(gt)), PosePath3D(poses_se3=list(est))))
    return float(metric.get_statistic(evo_metrics.StatisticsType.rmse))


def check_against_evo(scores: Scores, gt: np.ndarray, est: np.ndarray) -> None:
    """Every APE / RPE RMSE of ``scores`` equals evo's on the same trajectories."""
    for kind in ("ape", "rpe"):
        for relation in ("trans", "rot_rad"):
            expected = evo_rmse(gt, est, kind, relation)
            got = getattr(getattr(scores, kind), relation).rmse
            assert got == pytest.approx(expected, rel=1e-6, abs=1e-9), (kind, relation)


def test_own_mean_motion_is_the_sequences_mean_motion_repeated(tmp_path: Path) -> None:
    gt = varied_poses(0)
    sequence = write_sequence(tmp_path, "00", gt, seed=0)
    results = baselines.sequence_baselines(sequence, baselines.Training(np.eye(4), 0.1))
    assert tuple(results) == baselines.NAMES and baselines.OWN in baselines.NAMES
    steps = np.linalg.inv(gt[:-1]) @ gt[1:]
    u, _, vt = np.linalg.svd(steps[:, :3, :3].mean(axis=0))  # chordal L2 mean, projected onto SO(3)
    mean = np.eye(4)
    mean[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    mean[:3, 3] = steps[:, :3, 3].mean(axis=0)
    expected = chain([mean] * (FRAMES - 1))
    own = results[baselines.OWN]
    np.testing.assert_allclose(own.trajectory, expected, atol=1e-9)
    check_against_evo(own.scores, gt, expected)
    assert own.scores.rpe.trans.rmse > 0.1 and own.failures == 0  # varied steps: not exact


def test_zero_and_training_mean_motion_scores_equal_evos(tmp_path: Path) -> None:
    gt = varied_poses(5)
    train_step = step(0.01, 0.7, -0.02)
    results = baselines.sequence_baselines(
        write_sequence(tmp_path, "00", gt, seed=7), baselines.Training(train_step, 0.1)
    )
    standing = np.repeat(gt[:1], len(gt), axis=0)  # zero motion: the first pose forever
    np.testing.assert_allclose(results[baselines.ZERO].trajectory, standing, atol=1e-12)
    check_against_evo(results[baselines.ZERO].scores, gt, standing)
    chained = gt[0] @ chain([train_step] * (FRAMES - 1))
    np.testing.assert_allclose(results[baselines.MEAN].trajectory, chained, atol=1e-9)
    check_against_evo(results[baselines.MEAN].scores, gt, chained)
    check_against_evo(results[baselines.ORB].scores, gt, results[baselines.ORB].trajectory)


def test_own_mean_motion_is_exact_on_constant_velocity(tmp_path: Path) -> None:
    gt = chain([step(0.03, 0.8, 0.05)] * (FRAMES - 1))
    results = baselines.sequence_baselines(
        write_sequence(tmp_path, "00", gt, seed=1), baselines.Training(np.eye(4), 0.1)
    )
    own = results[baselines.OWN]
    np.testing.assert_allclose(own.trajectory, gt, atol=1e-9)
    for kind in ("trans", "rot_rad"):
        assert getattr(own.scores.rpe, kind).rmse < 1e-6 and getattr(own.scores.ape, kind).rmse < 1e-6


def data_record(
    root: Path, train_root: Path, train: tuple[str, ...], test: tuple[str, ...] = ()
) -> DataRecord:
    """A results.json data record of the KITTI-layout dataset at ``root`` (sequences ``test``) evaluating a
    network trained on ``train`` under ``train_root``."""
    kind = "lossvo.data.datamodules.KittiDataModule"
    return DataRecord(kind, str(root), list(test), [], str(train_root), list(train))


def recorded_data(root: Path, train: tuple[str, ...] = ("00",)) -> DataRecord:
    """A results.json data record of a KITTI-layout dataset evaluated on itself."""
    return data_record(root, root, train, test=("01",))


def test_results_are_cached_and_recomputed_when_the_frames_change(tmp_path: Path) -> None:
    root = tmp_path / "kitti"
    write_sequence(root, "00", varied_poses(1), seed=2)
    sequence = write_sequence(root, "01", varied_poses(2), seed=3)
    data = recorded_data(root)
    cache = tmp_path / "cache"
    first = baselines.compute_baselines(data, ["01"], cache)["01"]
    assert tuple(first) == baselines.NAMES and not any(r.cached for r in first.values())
    again = baselines.compute_baselines(data, ["01"], cache)["01"]
    assert tuple(again) == baselines.NAMES and all(r.cached for r in again.values())
    np.testing.assert_array_equal(again[baselines.ORB].trajectory, first[baselines.ORB].trajectory)
    frame = sequence.images[3]
    os.utime(frame, ns=(frame.stat().st_atime_ns, frame.stat().st_mtime_ns + 10**9))  # the frames changed
    third = baselines.compute_baselines(data, ["01"], cache)["01"]
    assert not any(r.cached for r in third.values())


def test_training_mean_motion_comes_from_the_recorded_training_data(tmp_path: Path) -> None:
    train_root, root = tmp_path / "train", tmp_path / "test"
    constant = step(0.02, 0.9, 0.03)
    write_sequence(train_root, "00", chain([constant] * (FRAMES - 1)), seed=4)
    write_sequence(root, "01", varied_poses(3), seed=5)
    data = data_record(root, train_root, ("00",), test=("01",))
    training = baselines.training_sequences(data)
    np.testing.assert_allclose(baselines.mean_motion([s.targets for s in training]), constant, atol=1e-9)
    results = baselines.compute_baselines(data, ["01"], tmp_path / "cache")["01"]
    gt = varied_poses(3)
    np.testing.assert_allclose(
        results[baselines.MEAN].trajectory, gt[0] @ chain([constant] * (FRAMES - 1)), atol=1e-9
    )
    with pytest.raises(UserError, match=r"data\.train"):
        baselines.training_sequences(data_record(root, train_root, ()))


def test_the_cache_is_keyed_by_the_training_split_the_scoring_and_the_flow_settings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tmp_path / "kitti"
    write_sequence(root, "00", varied_poses(1), seed=2)
    write_sequence(root, "02", varied_poses(5), seed=8)
    write_sequence(root, "01", varied_poses(4), seed=6)
    cache = tmp_path / "cache"
    baselines.compute_baselines(recorded_data(root), ["01"], cache)

    def cached(data: DataRecord, delta: int = 1) -> bool:
        found = baselines.compute_baselines(data, ["01"], cache, "none", delta)["01"]
        return all(r.cached for r in found.values())

    assert cached(recorded_data(root))
    assert not cached(recorded_data(root, ("00", "02")))  # another training split
    assert not cached(recorded_data(root), 2)  # another RPE delta
    monkeypatch.setattr(baselines, "ROAD_ROWS", (0.5, 1.0))  # another road region: other features
    assert not cached(recorded_data(root))


def test_a_sequence_of_several_datasets_names_its_recorded_source(tmp_path: Path) -> None:
    from lossvo.evaluation.job_folder import MULTI_LAYOUT, SourceRecord

    sources = {"car": SourceRecord("kitti", str(tmp_path), rendered=True)}
    for name in ("00", "drone/00"):  # no source named, or one not recorded
        with pytest.raises(
            UserError, match=rf"^sequence {name}: not <source>/<sequence> of a recorded dataset \(car\)"
        ):
            baselines.read_sequence(MULTI_LAYOUT, str(tmp_path), 1, sources, name)
    with pytest.raises(UserError, match=r"none recorded"):
        baselines.read_sequence(MULTI_LAYOUT, str(tmp_path), 1, {}, "car/00")
