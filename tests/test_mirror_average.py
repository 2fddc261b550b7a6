"""Mirror averaging at inference: the mirrored inputs, the average of two poses, its effect on a network."""

from __future__ import annotations

import math

import numpy as np
import pytest
import roma
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import DictConfig
from torch import Tensor, nn

from lossvo import geometry
from lossvo.data.transforms import mirror_inputs
from lossvo.evaluation.inference import average_with_mirror, predict_sequence
from lossvo.geometry import camera
from lossvo.train import CONFIG_DIR

S = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=torch.float64))


def _pose(rotvec: list[float], t: list[float]) -> Tensor:
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = roma.rotvec_to_rotmat(torch.tensor(rotvec, dtype=torch.float64))
    T[:3, 3] = torch.tensor(t, dtype=torch.float64)
    return T


def test_a_pose_and_its_exact_mirror_average_to_itself() -> None:
    T = _pose([0.01, -0.2, 0.03], [0.3, -0.1, 1.2])
    out = average_with_mirror(T[None], (S @ T @ S)[None])
    torch.testing.assert_close(out[0], T, atol=1e-12, rtol=0)


def test_the_average_is_the_geodesic_midpoint_and_the_mean_translation() -> None:
    yaw_a, yaw_b = 0.3, -0.1
    A = _pose([0.0, yaw_a, 0.0], [1.0, 0.0, 2.0])
    B = _pose([0.0, yaw_b, 0.0], [0.0, 0.5, 1.0])
    out = average_with_mirror(A[None], (S @ B @ S)[None])[0]
    expected = _pose([0.0, (yaw_a + yaw_b) / 2, 0.0], [0.5, 0.25, 1.5])
    torch.testing.assert_close(out, expected, atol=1e-12, rtol=0)
    assert geometry.rotation_angle(out[:3, :3] @ A[:3, :3].T).item() == pytest.approx(0.2, abs=1e-12)


def test_the_average_of_opposite_errors_cancels_them() -> None:
    """The network reads a true yaw of 0.04 as 0.09 (error +0.05); in the mirrored world the true yaw is
    -0.04 and the same error gives 0.01, which mirrored back is -0.01: the average is the truth."""
    truth = _pose([0.0, 0.04, 0.0], [0.0, 0.0, 1.0])
    plain = _pose([0.0, 0.09, 0.0], [0.0, 0.0, 1.0])
    mirrored_prediction = _pose([0.0, 0.01, 0.0], [0.0, 0.0, 1.0])
    out = average_with_mirror(plain[None], mirrored_prediction[None])[0]
    torch.testing.assert_close(out, truth, atol=1e-12, rtol=0)


def test_mirror_inputs_flips_frames_negates_u_and_mirrors_k() -> None:
    frames = torch.arange(2 * 3 * 2 * 5, dtype=torch.float32).reshape(2, 3, 2, 5)
    flow = torch.randn(1, 2, 2, 5)
    K = torch.tensor([[100.0, 0.0, 1.5], [0.0, 100.0, 1.0], [0.0, 0.0, 1.0]])
    out = mirror_inputs({"frames": frames, "flow": flow, "K": K, "other": torch.ones(1)})
    torch.testing.assert_close(out["frames"][..., 0], frames[..., 4])
    torch.testing.assert_close(out["flow"][:, 0, :, 0], -flow[:, 0, :, 4])
    torch.testing.assert_close(out["flow"][:, 1, :, 0], flow[:, 1, :, 4])
    torch.testing.assert_close(out["K"], camera.mirrored_intrinsics(K, 5))
    assert out["K"][0, 2].item() == pytest.approx(5 - 1 - 1.5)
    assert torch.equal(out["other"], torch.ones(1))


class _BiasedYaw(nn.Module):
    """A stand-in network that reads the yaw from the flow's mean u, with a constant bias: its plain and
    mirrored readings err in opposite directions, so mirror averaging removes the bias exactly."""

    def __init__(self, bias: float) -> None:
        super().__init__()
        self.bias = bias
        self.scale = nn.Parameter(torch.tensor(1.0))

    def forward(self, batch: dict[str, Tensor]) -> Tensor:
        u = batch["flow"][:, :, 0].mean(dim=(-1, -2))  # (B, L-1)
        yaw = -u * 0.01 + self.bias
        zeros = torch.zeros_like(yaw)
        return torch.stack([zeros, zeros, zeros + 1.0, zeros, yaw, zeros], dim=-1)

    def decode(self, pred: Tensor) -> Tensor:
        T = torch.zeros(*pred.shape[:-1], 4, 4, dtype=pred.dtype)
        T[..., :3, :3] = roma.rotvec_to_rotmat(pred[..., 3:])
        T[..., :3, 3] = pred[..., :3]
        T[..., 3, 3] = 1.0
        return T


@pytest.mark.parametrize("seq_len", [2, 4])
def test_predict_sequence_with_mirror_average_removes_a_mirror_asymmetric_bias(seq_len: int) -> None:
    n, h, w = 9, 4, 6
    u = torch.linspace(-3.0, 3.0, n - 1)
    flow = torch.zeros(n - 1, 2, h, w)
    flow[:, 0] = u.view(-1, 1, 1)
    inputs = {"frames": np.zeros((n, 3, h, w), np.uint8), "flow": flow.numpy().astype(np.float16),
              "K": np.eye(3, dtype=np.float32)}  # fmt: skip
    net = _BiasedYaw(bias=0.02)
    prepare = lambda x: {**x, "frames": x["frames"].float(), "flow": x["flow"].float()}  # noqa: E731
    plain = predict_sequence(net, inputs, prepare, seq_len)
    averaged = predict_sequence(net, inputs, prepare, seq_len, mirror_average=True)
    true_yaw = (-u * 0.01).double().numpy()
    plain_yaw = roma.rotmat_to_rotvec(torch.from_numpy(plain[:, :3, :3]))[:, 1].numpy()
    averaged_yaw = roma.rotmat_to_rotvec(torch.from_numpy(averaged[:, :3, :3]))[:, 1].numpy()
    np.testing.assert_allclose(plain_yaw, true_yaw + 0.02, atol=1e-3)
    np.testing.assert_allclose(averaged_yaw, true_yaw, atol=1e-3)
    assert math.isclose(float(np.abs(averaged[:, 2, 3] - 1.0).max()), 0.0, abs_tol=1e-6)


def _train_config(*overrides: str) -> DictConfig:
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        return compose("train", overrides=list(overrides), return_hydra_config=True)


def test_training_evaluates_with_mirror_averaging_by_default_in_validation_too() -> None:
    cfg = _train_config()
    assert cfg.mirror_average is True
    callback = instantiate(cfg.callbacks.trajectory_validation)
    assert callback.mirror_average is True
    off = _train_config("mirror_average=false")
    assert instantiate(off.callbacks.trajectory_validation).mirror_average is False
