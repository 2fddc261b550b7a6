"""lossvo.data.transforms: one test per batch transform (exact geometry, per-window draws), mirroring written
once, the upgrade of earlier checkpoints' augmentation arguments and transforms."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from lossvo import geometry
from lossvo.console import UserError
from lossvo.data import kitti
from lossvo.data import transforms as T
from lossvo.data.flow import mirror_flow
from lossvo.geometry import camera

S = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=torch.float64))


def drawn(p: float, size: int, seed: int) -> torch.Tensor:
    """The windows a transform of probability p selects with a generator seeded ``seed``."""
    return torch.rand(size, generator=torch.Generator().manual_seed(seed)) < p


def seed_selecting(p: float, size: int, wanted: list[bool]) -> int:
    """A seed whose first draw selects exactly the ``wanted`` windows."""
    return next(s for s in range(1000) if drawn(p, size, s).tolist() == wanted)


def trajectory_targets(root: Path, windows: int, frames: int) -> torch.Tensor:
    """(windows, frames - 1, 4, 4) float64 relative poses of consecutive stretches of sequence 00."""
    poses = torch.from_numpy(kitti.read_poses(root / "poses" / "00.txt"))
    return torch.stack([geometry.consecutive_relative_poses(poses[i * frames : (i + 1) * frames])
                        for i in range(windows)])  # fmt: skip


def test_mirror_is_the_mirrored_trajectory_through_the_mirrored_camera(tiny_kitti: Path) -> None:
    frames = torch.arange(2 * 5 * 3 * 2 * 4, dtype=torch.float32).view(2, 5, 3, 2, 4)
    flow = torch.randn(2, 4, 2, 2, 4)
    K = torch.tensor([[100.0, 0.0, 1.2], [0.0, 100.0, 1.0], [0.0, 0.0, 1.0]]).expand(2, 3, 3)
    targets = trajectory_targets(tiny_kitti, 1, 5).expand(2, 4, 4, 4)
    seed = seed_selecting(0.5, 2, [True, False])
    inputs = {"frames": frames, "flow": flow, "K": K, "other": torch.ones(2)}
    out, out_targets = T.Mirror(0.5)(inputs, targets, torch.Generator().manual_seed(seed))
    assert torch.equal(out["frames"][0], frames[0].flip(-1)) and torch.equal(out["frames"][1], frames[1])
    assert torch.equal(out["flow"][0], mirror_flow(flow[0])) and torch.equal(out["flow"][1], flow[1])
    assert torch.equal(out["K"][0], camera.mirrored_intrinsics(K[0], 4)) and torch.equal(out["K"][1], K[1])
    assert out["other"] is inputs["other"]
    poses = torch.from_numpy(kitti.read_poses(tiny_kitti / "poses" / "00.txt"))[:5]
    expected = geometry.consecutive_relative_poses(S @ poses @ S)  # the world seen in a mirror
    torch.testing.assert_close(out_targets[0], expected, atol=1e-12, rtol=0)
    assert torch.equal(out_targets[1], targets[1])
    # yaw and roll change sign, pitch does not (R = Ry(yaw) Rx(pitch) Rz(roll))
    euler, mirrored = (geometry.matrix_to_euler(t[:, :3, :3]) for t in (targets[0], out_targets[0]))
    torch.testing.assert_close(mirrored, euler * torch.tensor([-1.0, 1.0, -1.0], dtype=euler.dtype))
    twice, back = T.Mirror(0.5)(out, out_targets, torch.Generator().manual_seed(seed))
    assert all(torch.equal(twice[k], inputs[k]) for k in ("frames", "flow", "K"))
    assert torch.equal(back, targets)
    with pytest.raises(UserError, match=r"data\.transforms: Mirror\.p: expected a probability in \[0, 1\]"):
        T.Mirror(2)


def test_mirror_poses_is_s_t_s() -> None:
    poses = torch.randn(5, 3, 4, 4, dtype=torch.float64)
    torch.testing.assert_close(T.mirror_poses(poses), S @ poses @ S, atol=0, rtol=0)


def test_a_transform_round_trips_through_its_config() -> None:
    for transform in (T.Mirror(0.5), T.Roll(0.5, 0.01)):
        assert instantiate(T.spec(transform)) == transform


def roll_matrix(angle: float) -> torch.Tensor:
    """(4, 4) float64 Rz(angle): a turn about the camera's optical axis."""
    c, s = float(np.cos(angle)), float(np.sin(angle))
    return torch.tensor([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=torch.float64)


def scene_flow(K: torch.Tensor, T: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """(2, H, W) flow of a camera moving by T (frame 1 seen from frame 0) over a scene at ``depth`` (H, W)
    metres along frame 0's pixels."""
    H, W = depth.shape
    v, u = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64),
                          indexing="ij")  # fmt: skip
    x = torch.stack((u, v, torch.ones_like(u)))
    X0 = torch.einsum("ij,jhw->ihw", torch.linalg.inv(K), x) * depth
    X1 = torch.einsum("ji,jhw->ihw", T[:3, :3], X0 - T[:3, 3, None, None])
    q = torch.einsum("ij,jhw->ihw", K, X1)
    return q[:2] / q[2:] - x[:2]


def test_rolled_flow_and_targets_are_what_the_turned_cameras_see() -> None:
    """Frame 1 turned by a about its optical axis: the flow equals the analytic flow of the turned camera over
    the same scene (frame 0 is not resampled: to float precision) and the target is T Rz(a)."""
    H, W = 48, 160
    K = torch.tensor([[90.0, 0.0, 78.3], [0.0, 92.0, 25.1], [0.0, 0.0, 1.0]], dtype=torch.float64)
    T_rel = geometry.make_pose(torch.from_numpy(cv2.Rodrigues(np.array([0.01, 0.04, 0.002]))[0]),
                               torch.tensor([0.1, -0.05, 1.2], dtype=torch.float64))  # fmt: skip
    depth = 6.0 + torch.linspace(0.0, 4.0, H, dtype=torch.float64)[:, None].expand(H, W)
    inputs = {"frames": torch.randint(0, 256, (2, 2, 3, H, W), dtype=torch.uint8),
              "K": K.float().expand(2, 3, 3).clone(),
              "flow": scene_flow(K, T_rel, depth).float().expand(2, 1, 2, H, W).clone()}  # fmt: skip
    targets = T_rel.expand(2, 1, 4, 4).clone()
    angles = torch.tensor([[0.0, 0.03], [0.0, -0.2]])
    out, out_targets = T.rolled_windows(inputs, targets, angles)
    for b in range(2):
        turned = T_rel @ roll_matrix(float(angles[b, 1]))
        torch.testing.assert_close(out_targets[b, 0], turned, atol=1e-7, rtol=0)
        torch.testing.assert_close(
            out["flow"][b, 0].double(), scene_flow(K, turned, depth), atol=2e-3, rtol=0
        )
    assert torch.equal(out["frames"][:, 0], inputs["frames"][:, 0])  # the first camera is not turned
    assert out["frames"].dtype == torch.uint8 and out["flow"].dtype == torch.float32


def test_roll_turns_later_frames_through_the_resampled_flow() -> None:
    """Three frames, each after the first turned: pair 1's flow, read where turned frame 1's pixels were,
    is the analytic flow between the turned cameras within 0.02 px away from the border; the window's
    trajectory ends at the last camera turned (T_0 T_1 Rz(a_2))."""
    H, W = 48, 160
    K = torch.tensor([[90.0, 0.0, 79.5], [0.0, 90.0, 23.5], [0.0, 0.0, 1.0]], dtype=torch.float64)
    motions = (([0.0, 0.02, 0.0], [0.0, 0.0, 0.5]), ([0.01, -0.01, 0.0], [0.02, 0.0, 0.4]))
    steps = [geometry.make_pose(torch.from_numpy(cv2.Rodrigues(np.array(r))[0]), torch.tensor(t))
             for r, t in motions]  # fmt: skip
    depth = torch.full((H, W), 8.0, dtype=torch.float64)  # each pair: a wall 8 m ahead of its first camera
    flows = torch.stack([scene_flow(K, steps[0], depth), scene_flow(K, steps[1], depth)]).float()
    inputs = {
        "frames": torch.zeros(1, 3, 3, H, W, dtype=torch.uint8),
        "K": K.float()[None],
        "flow": flows[None],
    }
    angles = torch.tensor([[0.0, 0.05, -0.04]])
    out, out_targets = T.rolled_windows(inputs, torch.stack(steps)[None], angles)
    first, second = (roll_matrix(float(angles[0, k])) for k in (1, 2))
    torch.testing.assert_close(out_targets[0, 1], first.T @ steps[1] @ second, atol=1e-7, rtol=0)
    torch.testing.assert_close(out_targets[0, 0] @ out_targets[0, 1], steps[0] @ steps[1] @ second,
                               atol=1e-7, rtol=0)  # fmt: skip
    # the second pair seen from turned frame 1: its wall's depth along the turned camera's pixels
    v, u = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64),
                          indexing="ij")  # fmt: skip
    rays = torch.einsum("ij,jhw->ihw", torch.linalg.inv(K), torch.stack((u, v, torch.ones_like(u))))
    normal, offset = (
        torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
        8.0,
    )  # pair 1's wall: z = 8 in frame 1
    in_frame_1 = torch.einsum("ij,jhw->ihw", first[:3, :3], rays)  # turned frame 1's rays in frame 1's axes
    depth_1 = offset / torch.einsum("i,ihw->hw", normal, in_frame_1) * in_frame_1[2]
    expected = scene_flow(K, first.T @ steps[1] @ second, depth_1)
    inner = (slice(None), slice(4, -4), slice(8, -8))
    torch.testing.assert_close(out["flow"][0, 1].double()[inner], expected[inner], atol=0.02, rtol=0)


def test_roll_turns_only_the_drawn_windows_within_its_range() -> None:
    H, W = 16, 32
    K = torch.tensor([[30.0, 0.0, 15.5], [0.0, 30.0, 7.5], [0.0, 0.0, 1.0]])
    inputs = {"frames": torch.randint(0, 256, (3, 2, 3, H, W), dtype=torch.uint8), "K": K.expand(3, 3, 3),
              "flow": torch.randn(3, 1, 2, H, W)}  # fmt: skip
    targets = torch.eye(4).expand(3, 1, 4, 4).clone()
    seed = seed_selecting(0.5, 3, [True, False, True])
    out, out_targets = T.Roll(0.5, 0.1)(inputs, targets, torch.Generator().manual_seed(seed))
    rolls = torch.atan2(out_targets[:, 0, 1, 0], out_targets[:, 0, 0, 0])
    assert rolls[1] == 0 and rolls[[0, 2]].abs().min() > 0 and rolls.abs().max() <= 0.1
    torch.testing.assert_close(out["flow"][1], inputs["flow"][1], atol=1e-4, rtol=0)
    assert torch.equal(out["frames"][1], inputs["frames"][1])
    with pytest.raises(UserError, match=r"^data\.transforms: Roll\.max_rad: expected radians in \[0, 0\.5\]"):
        T.Roll(0.5, 1.0)
