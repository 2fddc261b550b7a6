"""lossvo.geometry: conventions, round trips, agreement with matrix_exp, gradients, shape errors."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from helpers import DEVICES
from lossvo import geometry as g

TOL = {torch.float32: 1e-6, torch.float64: 1e-12}
DTYPES = [torch.float32, torch.float64]
# Angles that stress the maps: exact zero, tiny, around the series switch, ordinary, and close to pi.
SPECIAL_ANGLES = [0.0, 1e-9, 1e-5, 0.279, 0.281, 1.0, 3.0, math.pi - 1e-3, math.pi - 1e-6]


def rotvecs(n: int, dtype: torch.dtype, device: str = "cpu", seed: int = 0) -> torch.Tensor:
    """(n + 3 * len(SPECIAL_ANGLES), 3) rotation vectors: random ones and special angles about 3 axes."""
    gen = torch.Generator().manual_seed(seed)
    axes = torch.randn(n + 3 * len(SPECIAL_ANGLES), 3, generator=gen, dtype=torch.float64)
    axes = axes / axes.norm(dim=-1, keepdim=True)
    angles = torch.cat(
        (math.pi * torch.rand(n, generator=gen, dtype=torch.float64), torch.tensor(SPECIAL_ANGLES * 3))
    )
    return (axes * angles[:, None]).to(dtype=dtype, device=device)


def rotations(n: int, dtype: torch.dtype, device: str = "cpu", seed: int = 0) -> torch.Tensor:
    """Rotation matrices built in float64 (exactly orthonormal to rounding), then cast."""
    return g.so3_exp(rotvecs(n, torch.float64, seed=seed)).to(dtype=dtype, device=device)


def assert_close(actual: torch.Tensor, expected: torch.Tensor, atol: float) -> None:
    torch.testing.assert_close(actual, expected.to(actual.dtype), atol=atol, rtol=0)


def Rx(a: float) -> torch.Tensor:
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=torch.float64)


def Ry(a: float) -> torch.Tensor:
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=torch.float64)


def Rz(a: float) -> torch.Tensor:
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=torch.float64)


# -- conventions ------------------------------------------------------------------------------------


def test_euler_convention_is_ry_rx_rz() -> None:
    yaw, pitch, roll = 0.3, -0.2, 0.1
    R = g.euler_to_matrix(torch.tensor([yaw, pitch, roll], dtype=torch.float64))
    assert_close(R, Ry(yaw) @ Rx(pitch) @ Rz(roll), 1e-15)


def test_quaternion_convention_is_wxyz() -> None:
    a = 0.7
    q = torch.tensor([math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)], dtype=torch.float64)
    assert_close(g.quat_to_matrix(q), Rz(a), 1e-15)
    assert_close(g.matrix_to_quat(Rz(a)), q, 1e-15)


def test_matrix_to_quat_is_canonical() -> None:
    q = g.matrix_to_quat(rotations(500, torch.float64))
    assert (q[:, 0] >= 0).all()
    assert_close(q.norm(dim=-1), torch.ones(len(q)), 1e-14)


def test_hat_vee() -> None:
    v, u = torch.randn(2, 10, 3, dtype=torch.float64).unbind(0)
    assert_close(g.hat(v) @ u[..., None], torch.linalg.cross(v, u)[..., None], 1e-15)
    assert_close(g.vee(g.hat(v)), v, 0)


def test_sixd_is_first_two_columns() -> None:
    R = rotations(20, torch.float64)
    assert_close(g.matrix_to_sixd(R)[:, :3], R[:, :, 0], 0)
    assert_close(g.matrix_to_sixd(R)[:, 3:], R[:, :, 1], 0)


# -- round trips (random rotations, plus angles near 0 and near pi) ---------------------------------


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_so3_exp_log_round_trip(dtype: torch.dtype, device: str) -> None:
    omega = rotvecs(1000, dtype, device)
    assert_close(g.so3_log(g.so3_exp(omega)), omega, TOL[dtype] * (4 if dtype == torch.float32 else 1))
    R = rotations(1000, dtype, device)
    assert_close(g.so3_exp(g.so3_log(R)), R, TOL[dtype])


def test_so3_exp_matches_matrix_exp() -> None:
    omega = rotvecs(500, torch.float64)
    assert_close(g.so3_exp(omega), torch.linalg.matrix_exp(g.hat(omega)), 1e-13)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_euler_round_trip(dtype: torch.dtype, device: str) -> None:
    R = rotations(1000, dtype, device)
    assert_close(g.euler_to_matrix(g.matrix_to_euler(R)), R, TOL[dtype])
    gen = torch.Generator().manual_seed(1)
    lo = torch.tensor([-math.pi, -math.pi / 2 + 1e-3, -math.pi], dtype=torch.float64)
    angles = lo + (-2 * lo) * torch.rand(1000, 3, generator=gen, dtype=torch.float64)
    angles = angles.to(dtype=dtype, device=device)
    # Away from gimbal lock the angles are unique; float32 loses up to ~1e-6 near pitch = +-pi/2.
    assert_close(
        g.matrix_to_euler(g.euler_to_matrix(angles)), angles, 3e-5 if dtype == torch.float32 else 1e-9
    )


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_quaternion_round_trip(dtype: torch.dtype, device: str) -> None:
    R = rotations(1000, dtype, device)
    q = g.matrix_to_quat(R)
    assert_close(g.quat_to_matrix(q), R, TOL[dtype])
    assert_close(g.matrix_to_quat(g.quat_to_matrix(q)), q, TOL[dtype])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_sixd_round_trip(dtype: torch.dtype, device: str) -> None:
    R = rotations(1000, dtype, device)
    assert_close(g.sixd_to_matrix(g.matrix_to_sixd(R)), R, TOL[dtype])


def test_sixd_of_arbitrary_vectors_is_a_rotation() -> None:
    R = g.sixd_to_matrix(3 * torch.randn(1000, 6, dtype=torch.float64))
    assert_close(R.transpose(-1, -2) @ R, torch.eye(3).expand(1000, 3, 3), 1e-12)
    assert_close(torch.linalg.det(R), torch.ones(1000), 1e-12)


def twists(n: int, dtype: torch.dtype, device: str = "cpu") -> torch.Tensor:
    gen = torch.Generator().manual_seed(2)
    omega = rotvecs(n, torch.float64)
    rho = 3 * torch.randn(len(omega), 3, generator=gen, dtype=torch.float64)
    return torch.cat((rho, omega), dim=-1).to(dtype=dtype, device=device)


def twist_matrix(xi: torch.Tensor) -> torch.Tensor:
    top = torch.cat((g.hat(xi[..., 3:]), xi[..., :3, None]), dim=-1)
    return torch.cat((top, torch.zeros_like(top[..., :1, :])), dim=-2)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_se3_exp_matches_matrix_exp(dtype: torch.dtype, device: str) -> None:
    xi = twists(1000, torch.float64)
    expected = torch.linalg.matrix_exp(twist_matrix(xi))
    # |rho| ~ 3 m: float32 translation rounding is ~ 3 * 6e-8 per operation.
    assert_close(
        g.se3_exp(xi.to(dtype=dtype, device=device)).cpu(),
        expected,
        1e-12 if dtype == torch.float64 else 2e-6,
    )


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_se3_exp_log_round_trip(dtype: torch.dtype, device: str) -> None:
    xi = twists(1000, dtype, device)
    T = g.se3_exp(xi)
    # Near pi, V^-1 amplifies rounding by ~1 / (pi - theta); so the twist is checked through its pose.
    assert_close(g.se3_exp(g.se3_log(T)), T, TOL[dtype] * (4 if dtype == torch.float32 else 10))
    ordinary = xi[:, 3:].norm(dim=-1) < 3.0
    assert_close(g.se3_log(T)[ordinary], xi[ordinary], 2e-5 if dtype == torch.float32 else 1e-12)


def test_left_jacobian_inverse() -> None:
    omega = rotvecs(500, torch.float64)
    product = g.so3_left_jacobian(omega) @ g.so3_left_jacobian_inv(omega)
    # 1 / (pi - theta) amplification for the special angles closest to pi.
    assert_close(product, torch.eye(3, dtype=torch.float64).expand_as(product), 1e-9)


@given(st.lists(st.floats(-4.0, 4.0, allow_nan=False), min_size=6, max_size=6))
def test_se3_round_trip_property(values: list[float]) -> None:
    xi = torch.tensor(values, dtype=torch.float64)
    if xi[3:].norm() >= math.pi - 1e-3:
        xi[3:] *= (math.pi - 1e-3) / xi[3:].norm()
    assert_close(g.se3_exp(g.se3_log(g.se3_exp(xi))), g.se3_exp(xi), 1e-12)


# -- poses ------------------------------------------------------------------------------------------


def random_poses(n: int, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    return g.se3_exp(twists(n, torch.float64)).to(dtype)


def test_pose_inverse() -> None:
    T = random_poses(100)
    assert_close(g.pose_inverse(T), torch.linalg.inv(T), 1e-12)
    assert_close(T @ g.pose_inverse(T), torch.eye(4).expand_as(T), 1e-12)


def test_relative_pose_convention() -> None:
    T_w = random_poses(10)
    rel = g.consecutive_relative_poses(T_w)
    assert rel.shape == (len(T_w) - 1, 4, 4)
    assert_close(rel, torch.linalg.inv(T_w[:-1]) @ T_w[1:], 1e-12)
    assert_close(T_w[:-1] @ rel, T_w[1:], 1e-12)  # integration: T_w_{k+1} = T_w_k @ T_k


def test_relative_pose_in_float64_then_cast() -> None:
    # Large translations (kilometres, as at the end of a KITTI sequence): float32 arithmetic would
    # lose centimetres; the relative pose is computed in float64 and only then cast.
    T_w = random_poses(50)
    T_w[:, :3, 3] += 2000.0
    T32 = T_w.float()
    expected = (torch.linalg.inv(T32[:-1].double()) @ T32[1:].double()).float()
    rel = g.consecutive_relative_poses(T32)
    assert rel.dtype == torch.float32
    torch.testing.assert_close(rel, expected, atol=1e-6, rtol=0)


def test_orthonormalize() -> None:
    R = rotations(100, torch.float64)
    assert_close(g.orthonormalize(R), R, 1e-12)
    noisy = R + 1e-3 * torch.randn_like(R)
    Q = g.orthonormalize(noisy)
    assert_close(Q.transpose(-1, -2) @ Q, torch.eye(3).expand_as(Q), 1e-12)
    assert (g.so3_geodesic_distance(Q, R) < 1e-2).all()


# -- distances --------------------------------------------------------------------------------------


def test_distances_closed_forms() -> None:
    R_a, R_b = rotations(300, torch.float64, seed=3), rotations(300, torch.float64, seed=4)
    theta = g.so3_log(R_a.transpose(-1, -2) @ R_b).norm(dim=-1)
    assert_close(g.so3_geodesic_distance(R_a, R_b), theta, 1e-12)
    assert_close(g.so3_chordal_distance(R_a, R_b), 2 * math.sqrt(2) * torch.sin(theta / 2), 1e-12)
    q_a, q_b = g.matrix_to_quat(R_a), g.matrix_to_quat(R_b)
    assert_close(g.quat_distance(q_a, q_b), 2 * torch.sin(theta / 4), 1e-12)
    assert_close(g.quat_distance(q_a, -q_b), g.quat_distance(q_a, q_b), 0)


@pytest.mark.parametrize("angle", [1e-12, 1e-9, 1e-7, 1e-3, math.pi - 1e-7, math.pi])
def test_rotation_angle_is_accurate_at_both_ends(angle: float) -> None:
    # arccos(clamp((tr - 1) / 2)) would give ~1e-8 for every angle below 1e-8: a floor under errors.
    R = g.so3_exp(torch.tensor([0.0, angle, 0.0], dtype=torch.float64))
    assert g.rotation_angle(R).item() == pytest.approx(angle, rel=1e-9)


def test_se3_chordal_distance() -> None:
    T_a, T_b = random_poses(50), random_poses(50)
    assert_close(g.se3_chordal_distance(T_a, T_b), torch.linalg.matrix_norm(T_a - T_b), 1e-12)
    d = g.se3_chordal_distance(T_a, T_b, weight=153.0)
    dt = (T_a[:, :3, 3] - T_b[:, :3, 3]).norm(dim=-1)
    assert_close(
        d.square(),
        dt.square() + 153.0 * g.so3_chordal_distance(T_a[:, :3, :3], T_b[:, :3, :3]).square(),
        1e-9,
    )
    with pytest.raises(ValueError, match="weight must be >= 0"):
        g.se3_chordal_distance(T_a, T_b, weight=-1.0)


# -- gradients --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_gradcheck() -> None:
    xi = twists(5, torch.float64).requires_grad_()
    assert torch.autograd.gradcheck(g.se3_exp, (xi,))
    xi = twists(5, torch.float64)
    # Finite differences (step 1e-6) must not cross pi, where the logarithm jumps.
    T = g.se3_exp(xi[xi[:, 3:].norm(dim=-1) < 3.0])
    assert torch.autograd.gradcheck(g.se3_log, (T.requires_grad_(),))
    # Random pairs only: at zero distance the angle has a cusp (like |x|) and no derivative.
    R_a, R_b = rotations(4, torch.float64, seed=5)[:4], rotations(4, torch.float64, seed=6)[:4]
    assert torch.autograd.gradcheck(g.so3_geodesic_distance, (R_a.requires_grad_(), R_b))


NEAR_PI = math.radians(179.9)


@pytest.mark.parametrize("angle", [0.0, 1e-6, NEAR_PI, math.pi])
@pytest.mark.parametrize("dtype", DTYPES)
def test_gradients_finite_at_identity_and_near_pi(angle: float, dtype: torch.dtype) -> None:
    omega = torch.tensor([[0.0, angle, 0.0], [angle / math.sqrt(2), 0.0, angle / math.sqrt(2)]], dtype=dtype)
    xi = torch.cat((torch.ones_like(omega), omega), dim=-1).requires_grad_()
    T = g.se3_exp(xi)
    R_target = g.so3_exp(torch.zeros_like(omega))
    total = (
        g.so3_geodesic_distance(T[..., :3, :3], R_target).sum()
        + g.so3_chordal_distance(T[..., :3, :3], R_target).sum()
        + g.so3_geodesic_distance(T[..., :3, :3], T[..., :3, :3].detach()).sum()  # zero distance
        + g.se3_log(T).sum()
        + g.quat_distance(g.matrix_to_quat(T[..., :3, :3]), g.matrix_to_quat(R_target)).sum()
        + g.matrix_to_euler(T[..., :3, :3]).sum()
    )
    (grad,) = torch.autograd.grad(total, xi)
    assert torch.isfinite(grad).all()


def test_quat_normalize_zero_and_nan() -> None:
    q = torch.zeros(2, 4, dtype=torch.float64)
    q[1] = float("nan")
    q.requires_grad_()
    out = g.quat_normalize(q)
    assert_close(out[0], torch.tensor([1.0, 0.0, 0.0, 0.0]), 0)
    assert torch.isnan(out[1]).all()
    (grad,) = torch.autograd.grad(out[0].sum(), q)
    assert torch.isfinite(grad[0]).all()


# -- batching and shapes ----------------------------------------------------------------------------


def test_any_leading_dims() -> None:
    xi = twists(24, torch.float64)[:24].reshape(2, 3, 4, 6)
    T = g.se3_exp(xi)
    assert T.shape == (2, 3, 4, 4, 4)
    assert_close(T.reshape(-1, 4, 4), g.se3_exp(xi.reshape(-1, 6)), 0)
    assert g.so3_geodesic_distance(T[..., :3, :3], T[..., :3, :3]).shape == (2, 3, 4)


@pytest.mark.parametrize(
    ("fn", "bad", "expected"),
    [
        (g.so3_exp, torch.zeros(5, 4), r"omega must have shape \(\.\.\., 3\), got \(5, 4\)"),
        (g.se3_exp, torch.zeros(5, 3), r"xi must have shape \(\.\.\., 6\), got \(5, 3\)"),
        (g.se3_log, torch.zeros(5, 3, 3), r"T must have shape \(\.\.\., 4, 4\), got \(5, 3, 3\)"),
        (g.matrix_to_quat, torch.zeros(3), r"R must have shape \(\.\.\., 3, 3\), got \(3,\)"),
        (g.sixd_to_matrix, torch.zeros(2, 9), r"x must have shape \(\.\.\., 6\), got \(2, 9\)"),
        (g.consecutive_relative_poses, torch.zeros(4, 4), r"T_w must have shape \(\.\.\., N, 4, 4\)"),
    ],
)
def test_shape_errors_name_expected_and_received(fn, bad: torch.Tensor, expected: str) -> None:
    with pytest.raises(ValueError, match=expected):
        fn(bad)
