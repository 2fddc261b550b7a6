"""lossvo.data.transforms: one test per batch transform (exact geometry, per-window draws), mirroring written
once, the upgrade of earlier checkpoints' augmentation arguments."""

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


def test_standstill_shows_no_motion_with_fresh_noise() -> None:
    torch.manual_seed(0)
    frames = torch.randint(20, 236, (3, 5, 3, 16, 16), dtype=torch.uint8)
    flow = torch.randn(3, 4, 2, 16, 16)
    targets = torch.randn(3, 4, 4, 4, dtype=torch.float64)
    seed = seed_selecting(0.5, 3, [True, False, True])
    inputs = {"frames": frames, "flow": flow, "K": torch.eye(3).expand(3, 3, 3)}
    out, out_targets = T.Standstill(0.5)(inputs, targets, torch.Generator().manual_seed(seed))
    assert out["frames"].dtype == torch.uint8 and out_targets.dtype == torch.float64
    assert torch.equal(out["frames"][1], frames[1]) and torch.equal(out_targets[1], targets[1])
    assert torch.equal(out_targets[[0, 2]], torch.eye(4, dtype=torch.float64).expand(2, 4, 4, 4))
    assert torch.equal(out["flow"][[0, 2]], torch.zeros(2, 4, 2, 16, 16))
    assert torch.equal(out["flow"][1], flow[1])
    noise = out["frames"][[0, 2]].float() - frames[[0, 2], :1].float()
    assert abs(noise.mean().item()) < 0.05 and abs(noise.std().item() - T.STANDSTILL_NOISE) < 0.1
    assert not torch.equal(out["frames"][0, 1], out["frames"][0, 2])  # each frame its own noise
    none, _ = T.Standstill(0.0)(inputs, targets)
    assert none["frames"] is frames


def rotation_flow(K: torch.Tensor, R: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """(2, H, W) flow of a pure camera rotation: pixel x goes to K R K^-1 x (dehomogenised)."""
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64),
                          indexing="ij")  # fmt: skip
    x = torch.stack((u, v, torch.ones_like(u)))
    p = torch.einsum("ij,jhw->ihw", K @ R @ torch.linalg.inv(K), x)
    return p[:2] / p[2:] - x[:2]


def test_zoomed_flow_is_the_flow_the_zoomed_camera_sees() -> None:
    """The flow of a camera rotation, zoomed with K, equals the flow of that rotation computed with the
    zoomed K (bilinear resampling of a smooth field: within 0.02 px); targets are unchanged."""
    H, W = 64, 208
    K = torch.tensor([[120.0, 0.0, 103.2], [0.0, 122.0, 31.4], [0.0, 0.0, 1.0]], dtype=torch.float64)
    R = torch.from_numpy(cv2.Rodrigues(np.array([0.01, 0.03, 0.005]))[0])
    flow = rotation_flow(K, R, H, W)
    inputs = {"frames": torch.zeros(3, 2, 3, H, W, dtype=torch.uint8), "K": K.expand(3, 3, 3).clone(),
              "flow": flow.expand(3, 1, 2, H, W).clone()}  # fmt: skip
    targets = torch.randn(3, 1, 4, 4)
    out, out_targets = T.Zoom(1.8)(inputs, targets, torch.Generator().manual_seed(0))
    assert out_targets is targets
    assert out["frames"].dtype == torch.uint8 and out["flow"].shape == (3, 1, 2, H, W)
    for b in range(3):
        zoom = out["K"][b, 0, 0] / K[0, 0]
        assert 1.0 <= zoom <= 1.8
        expected = rotation_flow(out["K"][b], R, H, W)
        torch.testing.assert_close(
            out["flow"][b, 0, :, 1:-1, 1:-1], expected[:, 1:-1, 1:-1], atol=0.02, rtol=0
        )
    assert not torch.allclose(out["K"][0], out["K"][1])  # one draw a window
    with pytest.raises(UserError, match=r"data\.transforms: Zoom\.factor: expected a number in \[1, 4\]"):
        T.Zoom(0.5)


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


def test_reverse_plays_the_window_backwards_exactly(tiny_kitti: Path) -> None:
    frames = torch.arange(2 * 4).view(2, 4, 1, 1, 1).expand(2, 4, 3, 2, 2)  # frame index as pixel value
    targets = trajectory_targets(tiny_kitti, 2, 4)
    seed = seed_selecting(0.5, 2, [True, False])
    out, out_targets = T.Reverse(0.5)({"frames": frames}, targets, torch.Generator().manual_seed(seed))
    assert out["frames"][0, :, 0, 0, 0].tolist() == [3, 2, 1, 0] and torch.equal(out["frames"][1], frames[1])
    # backwards, pair k goes from frame 3-k to frame 2-k: inv(T_w_{3-k}) @ T_w_{2-k}
    poses = torch.from_numpy(kitti.read_poses(tiny_kitti / "poses" / "00.txt"))
    expected = geometry.consecutive_relative_poses(poses[0:4].flip(0))
    # (pose_inverse transposes R; the file's rotations are orthonormal to its 9 digits)
    torch.testing.assert_close(out_targets[0], expected, atol=1e-9, rtol=0)
    assert torch.equal(out_targets[1], targets[1])
    with pytest.raises(UserError, match=r"data\.transforms: Reverse\.p: expected a probability in \[0, 1\]"):
        T.Reverse(1.5)


def test_jitter_changes_brightness_and_contrast_once_a_window() -> None:
    frames = torch.full((3, 4, 3, 8, 8), 100, dtype=torch.uint8)
    frames[:, :, :, :4] = 160
    targets = torch.randn(3, 3, 4, 4)
    out, out_targets = T.Jitter()({"frames": frames}, targets, torch.Generator().manual_seed(0))
    gain, bias = torch.rand(2, 3, generator=torch.Generator().manual_seed(0)) - 0.5
    assert out_targets is targets and out["frames"].dtype == torch.float32
    assert torch.equal(out["frames"], out["frames"].round()) and out["frames"].min() >= 0
    for b in range(3):  # contrast 1 + 0.4 g about 127.5, brightness 50 b; one draw for the whole window
        expected = ((frames[b].float() - 127.5) * (1 + 0.4 * gain[b]) + 127.5 + 50 * bias[b]).round()
        torch.testing.assert_close(out["frames"][b], expected.clamp(0, 255), atol=0, rtol=0)
    assert not torch.equal(out["frames"][0], out["frames"][1])


def test_mirror_poses_is_s_t_s() -> None:
    poses = torch.randn(5, 3, 4, 4, dtype=torch.float64)
    torch.testing.assert_close(T.mirror_poses(poses), S @ poses @ S, atol=0, rtol=0)


def test_a_transform_round_trips_through_its_config() -> None:
    for transform in (
        T.Standstill(0.1),
        T.Zoom(1.5),
        T.Mirror(0.5),
        T.Roll(0.5, 0.01),
        T.Reverse(0.3),
        T.Jitter(),
    ):
        assert instantiate(T.spec(transform)) == transform


def test_earlier_augmentation_arguments_become_transforms_in_their_order() -> None:
    old = {"_target_": "x", "seq_len": 3, "augment": True, "reverse": 0.0, "standstill": 0.2, "mirror": 0.5,
           "zoom": 1.0}  # fmt: skip
    new = T.upgrade_description(old)
    listed = [T.spec(T.Standstill(0.2)), T.spec(T.Mirror(0.5)), T.spec(T.Jitter())]
    assert new == {"_target_": "x", "seq_len": 3, "transforms": listed}
    assert T.upgrade_description(new) is new and T.upgrade_description(None) is None


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
