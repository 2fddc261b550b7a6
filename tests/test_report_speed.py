"""The report's speed section: how the predicted speed follows the true one on the slowest and fastest
stretches, against hand-made trajectories whose ratios are known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lossvo.data.pose_files import write_poses
from lossvo.report import speed
from lossvo.report.jobs import Job
from lossvo.report.tables import NETWORK, Column


def _straight(steps: np.ndarray) -> np.ndarray:
    """(N + 1, 4, 4) poses driving straight ahead (z) by ``steps`` (N,) metres, turning a little."""
    poses = np.tile(np.eye(4), (len(steps) + 1, 1, 1))
    for k, step in enumerate(steps):
        c, s = np.cos(0.01), np.sin(0.01)
        relative = np.eye(4)
        relative[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
        relative[2, 3] = step
        poses[k + 1] = poses[k] @ relative
    return poses


TRUE = np.linspace(0.1, 1.0, 10)  # the slowest fifth: 0.1, 0.2; the fastest: 0.9, 1.0


def test_stretches_are_the_slowest_and_fastest_fifth_by_true_step_length() -> None:
    masks = speed.stretches(np.array([0.5, 0.1, 0.9, 0.3, 0.7]))
    assert masks["slowest"].tolist() == [False, True, False, False, False]
    assert masks["fastest"].tolist() == [False, False, True, False, False]
    assert masks["all"].all()
    np.testing.assert_allclose(speed.step_lengths(_straight(TRUE)), TRUE)


def test_speed_ratios_are_mean_predicted_over_mean_true_per_stretch() -> None:
    scale = np.where(TRUE < 0.25, 1.5, np.where(TRUE > 0.85, 0.8, 1.0))  # slow read fast, fast read slow
    ratios = speed.speed_ratios(_straight(TRUE * scale), _straight(TRUE))
    assert ratios["slowest"] == pytest.approx(1.5) and ratios["fastest"] == pytest.approx(0.8)
    assert ratios["all"] == pytest.approx((TRUE * scale).sum() / TRUE.sum())


def test_rows_give_each_configuration_mean_and_std_over_seeds(tmp_path: Path, monkeypatch) -> None:
    """Two seeds reading every step 1.1x and 1.3x too long: 1.200 ± 0.14 on every stretch; a trajectory of
    another length (a different dataset) is left out; training sequences are left out."""
    monkeypatch.setattr(speed, "training_sequences", lambda columns: {"00"})
    jobs = []
    for seed, factor in enumerate((1.1, 1.3)):
        job = Job(tmp_path / f"job{seed}")
        (job.path / "trajectories").mkdir(parents=True)
        write_poses(job.path / "trajectories" / "07.txt", _straight(TRUE * factor))
        jobs.append(job)
    other = Job(tmp_path / "other")
    (other.path / "trajectories").mkdir(parents=True)
    write_poses(other.path / "trajectories" / "07.txt", _straight(TRUE[:5]))
    column = Column("loss=euler", NETWORK, ["seed=0", "seed=1", "seed=2"], [{}, {}, {}], [*jobs, other])
    gt = {"00": _straight(TRUE), "07": _straight(TRUE)}
    rows = speed.speed_rows([column], gt, ["00", "07", "11"])
    assert rows.header[:2] == ["configuration", "sequence"] and len(rows.rows) == 1
    label, sequence, *cells = rows.rows[0]
    assert (label, sequence) == ("loss=euler", "07")
    assert cells == ["0.150", "1.20 ± 0.14", "0.950", "1.20 ± 0.14", "0.550", "1.20 ± 0.14"]


def test_rows_of_several_architectures_name_each_rows_architecture(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(speed, "training_sequences", lambda columns: set())
    columns = []
    for architecture in ("deepvo_small", "flowvo"):
        job = Job(tmp_path / architecture)
        (job.path / "trajectories").mkdir(parents=True)
        write_poses(job.path / "trajectories" / "07.txt", _straight(TRUE))
        label = f"model={architecture},loss=euler"
        columns.append(Column(label, NETWORK, ["seed=0"], [{}], [job], architecture=architecture))
    rows = speed.speed_rows(columns, {"07": _straight(TRUE)}, ["07"])
    assert rows.header[:3] == ["architecture", "configuration", "sequence"]
    assert [row[:3] for row in rows.rows] == [
        ["deepvo_small", "model=deepvo_small,loss=euler", "07"], ["flowvo", "model=flowvo,loss=euler", "07"]
    ]  # fmt: skip
    assert rows.rows[0][4] == "1.00"  # one seed: no std
