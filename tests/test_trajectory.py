"""lossvo.evaluation.trajectories: chaining (vs a sequential reference), TUM files (round trips with evo)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from evo.core.trajectory import PoseTrajectory3D
from evo.tools import file_interface

from lossvo import geometry
from lossvo.data.kitti import KittiFormatError
from lossvo.evaluation.trajectories import integrate, read_tum, write_tum


def relative_steps(n: int, seed: int = 0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    xi = 0.05 * torch.randn(n, 6, generator=gen, dtype=torch.float64)
    xi[:, 2] += 1.0  # about 1 m forward per step
    return geometry.se3_exp(xi)


def sequential(start: torch.Tensor, relative: torch.Tensor) -> torch.Tensor:
    poses = [start]
    for T in relative:  # the reference: one pose at a time
        poses.append(poses[-1] @ T)
    return torch.stack(poses)


@pytest.mark.parametrize("n", [1, 2, 7, 100, 1000])
def test_integrate_equals_sequential_chaining(n: int) -> None:
    rel = relative_steps(n)
    start = geometry.se3_exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3], dtype=torch.float64))
    torch.testing.assert_close(integrate(rel, start), sequential(start, rel), atol=1e-9, rtol=1e-12)


def test_integrate_inverts_relative_poses() -> None:
    poses = integrate(relative_steps(500, seed=1))
    rel = geometry.consecutive_relative_poses(poses)
    torch.testing.assert_close(integrate(rel, poses[0]), poses, atol=1e-9, rtol=0)


@pytest.mark.slow
def test_chained_rotations_stay_orthonormal() -> None:
    rel = relative_steps(5000, seed=2).float().double()  # rounded steps, slightly non-orthonormal
    R = integrate(rel)[:, :3, :3]
    torch.testing.assert_close(
        R.transpose(1, 2) @ R, torch.eye(3, dtype=torch.float64).expand_as(R), atol=1e-12, rtol=0
    )


def test_integrate_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match=r"relative must have shape \(N-1, 4, 4\), got \(2, 3, 4, 4\)"):
        integrate(torch.zeros(2, 3, 4, 4))


def test_tum_round_trip_with_evo(tmp_path: Path) -> None:
    poses = integrate(relative_steps(200, seed=3)).numpy()
    times = np.arange(len(poses)) * 0.1
    path = tmp_path / "traj.tum"
    write_tum(path, times, poses)
    traj = file_interface.read_tum_trajectory_file(str(path))
    np.testing.assert_allclose(np.stack(traj.poses_se3), poses, atol=1e-8)
    np.testing.assert_allclose(traj.timestamps, times, atol=1e-9)
    evo_path = tmp_path / "evo.tum"
    file_interface.write_tum_trajectory_file(
        str(evo_path), PoseTrajectory3D(poses_se3=list(poses), timestamps=times)
    )
    read_times, read_poses = read_tum(evo_path)
    np.testing.assert_allclose(read_poses, poses, atol=1e-8)
    np.testing.assert_allclose(read_times, times, atol=1e-9)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("0.1 1 2 3 0 0 0", r"traj\.tum:3: expected 8 finite numbers"),
        ("0.1 1 2 3 0 0 0 0", r"traj\.tum:3: quaternion"),
    ],
)
def test_bad_tum_line_is_named(tmp_path: Path, line: str, message: str) -> None:
    path = tmp_path / "traj.tum"
    path.write_text("# timestamp tx ty tz qx qy qz qw\n0.0 0 0 0 0 0 0 1\n" + line + "\n")
    with pytest.raises(KittiFormatError, match=message):
        read_tum(path)
