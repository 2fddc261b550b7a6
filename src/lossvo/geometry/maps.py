"""Batched SO(3) / SE(3) maps and conversions: exp / log, the SE(3) V matrix, Euler angles, quaternions,
6-D rotations, poses. Any leading dimensions, float32 or float64, any device; finite gradients at the
identity and near 180 degrees. Conventions (KITTI odometry; Barfoot, *State Estimation for Robotics*):

- A pose is a 4x4 camera-to-world matrix ``T_w_c``; camera axes x right, y down, z forward.
- se(3) vectors are ``xi = (rho, omega)``: ``Exp(xi) = [[exp(omega^), V(omega) rho], [0, 1]]``.
- Euler angles are ``(yaw, pitch, roll)`` in radians, ``R = Ry(yaw) @ Rx(pitch) @ Rz(roll)``.
- Quaternions are ``(w, x, y, z)``; conversions from matrices return the canonical sign ``w >= 0``.
- 6-D rotations are the first two columns of the matrix, ``(c1, c2)``, mapped back by Gram-Schmidt.

RoMa does the rotation maths; written here is what it lacks: the SE(3) exp / log (the V matrix and its
inverse).
"""

from __future__ import annotations

import roma
import torch
from torch import Tensor

EULER_CONVENTION = "YXZ"
"""RoMa's name for R = Ry(yaw) @ Rx(pitch) @ Rz(roll) (intrinsic rotations about y, then x, then z)."""


def check_shape(x: Tensor, tail: tuple[int, ...], name: str) -> None:
    """Raise a ValueError unless ``x`` has shape ``(..., *tail)``."""
    if x.dim() < len(tail) or tuple(x.shape[x.dim() - len(tail) :]) != tail:
        expected = "(..., " + ", ".join(map(str, tail)) + ")"
        raise ValueError(f"{name} must have shape {expected}, got {tuple(x.shape)}")


# --------------------------------------------------------------------------------------------------
# so(3): hat / vee, exponential and logarithm
# --------------------------------------------------------------------------------------------------


def hat(v: Tensor) -> Tensor:
    """Skew-symmetric matrices, (..., 3) -> (..., 3, 3): ``hat(v) @ u == cross(v, u)``."""
    check_shape(v, (3,), "v")
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    rows = (zero, -z, y, z, zero, -x, -y, x, zero)
    return torch.stack(rows, dim=-1).unflatten(-1, (3, 3))


def vee(W: Tensor) -> Tensor:
    """The vector of ``W``'s skew part, (..., 3, 3) -> (..., 3); the inverse of :func:`hat`."""
    check_shape(W, (3, 3), "W")
    return 0.5 * torch.stack(
        (W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]), dim=-1
    )


def so3_exp(omega: Tensor) -> Tensor:
    """Rotation vectors (radians) to rotation matrices, (..., 3) -> (..., 3, 3) (Rodrigues)."""
    check_shape(omega, (3,), "omega")
    return roma.rotvec_to_rotmat(omega)


def so3_log(R: Tensor) -> Tensor:
    """Rotation matrices to rotation vectors with angle in [0, pi], (..., 3, 3) -> (..., 3)."""
    check_shape(R, (3, 3), "R")
    return roma.rotmat_to_rotvec(R)


# --------------------------------------------------------------------------------------------------
# SE(3): exponential and logarithm (RoMa has no SE(3) Lie algebra maps)
# --------------------------------------------------------------------------------------------------


# Taylor coefficients in s = theta^2 of b, c, d below (the first five terms of each series).
_B_SERIES = (1 / 2, -1 / 24, 1 / 720, -1 / 40320, 1 / 3628800)
_C_SERIES = (1 / 6, -1 / 120, 1 / 5040, -1 / 362880, 1 / 39916800)
_D_SERIES = (1 / 12, 1 / 720, 1 / 30240, 1 / 1209600, 1 / 47900160)


_SERIES_BELOW = 0.28
"""Angle (radians) below which b, c, d use their series, always in float64: there the closed forms lose
about ``6 eps / t^2`` to cancellation and the series drop ``t^10 / 1.6e8``, both about 2e-14."""


def _polyval(coefficients: tuple[float, ...], s: Tensor) -> Tensor:
    """``sum_i coefficients[i] * s**i`` by Horner's rule."""
    out = torch.full_like(s, coefficients[-1])
    for c in reversed(coefficients[:-1]):
        out = out * s + c
    return out


def _v_coefficients(theta2: Tensor) -> tuple[Tensor, Tensor]:
    """``b = (1 - cos t) / t^2`` and ``c = (t - sin t) / t^3`` of ``V = I + b W + c W^2``, (...) -> (...).

    ``theta2`` is ``t^2 = |omega|^2``. Near zero a series in ``t^2`` (finite gradients where ``sqrt`` has
    none); elsewhere the closed form, fed a dummy ``t = 1`` where the series is used.
    """
    dtype, small, theta2, t2 = _series_split(theta2)
    t = torch.sqrt(t2)
    half = 0.5 * t
    b_closed = 0.5 * (torch.sin(half) / half) ** 2  # = (1 - cos t) / t^2 without cancellation
    c_closed = (t - torch.sin(t)) / (t2 * t)
    return (
        torch.where(small, _polyval(_B_SERIES, theta2), b_closed).to(dtype),
        torch.where(small, _polyval(_C_SERIES, theta2), c_closed).to(dtype),
    )


def _v_inverse_coefficient(theta2: Tensor) -> Tensor:
    """``d = (1 - (t/2) cot(t/2)) / t^2`` of ``V^-1 = I - W/2 + d W^2``, by the rule of
    :func:`_v_coefficients`, (...) -> (...)."""
    dtype, small, theta2, t2 = _series_split(theta2)
    half = 0.5 * torch.sqrt(t2)
    d_closed = (1.0 - half * torch.cos(half) / torch.sin(half)) / t2
    return torch.where(small, _polyval(_D_SERIES, theta2), d_closed).to(dtype)


def _series_split(theta2: Tensor) -> tuple[torch.dtype, Tensor, Tensor, Tensor]:
    """The input's dtype, where the series is used, ``theta2`` in float64, and ``theta2`` with a dummy 1
    where the series is used (what the closed forms are fed)."""
    dtype = theta2.dtype
    theta2 = theta2.double()
    small = theta2 < _SERIES_BELOW**2
    return dtype, small, theta2, torch.where(small, torch.ones_like(theta2), theta2)


def so3_left_jacobian(omega: Tensor) -> Tensor:
    """The V matrix of the SE(3) exponential (SO(3)'s left Jacobian), (..., 3) -> (..., 3, 3)."""
    check_shape(omega, (3,), "omega")
    b, c = _v_coefficients((omega * omega).sum(-1))
    W = hat(omega)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device)
    return eye + b[..., None, None] * W + c[..., None, None] * (W @ W)


def so3_left_jacobian_inv(omega: Tensor) -> Tensor:
    """Inverse of :func:`so3_left_jacobian` for angles below 2 pi, (..., 3) -> (..., 3, 3)."""
    check_shape(omega, (3,), "omega")
    d = _v_inverse_coefficient((omega * omega).sum(-1))
    W = hat(omega)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device)
    return eye - 0.5 * W + d[..., None, None] * (W @ W)


def se3_exp(xi: Tensor) -> Tensor:
    """Exponential map se(3) -> SE(3), (..., 6) twists ``(rho [m], omega [rad])`` -> (..., 4, 4) poses;
    equal to ``torch.linalg.matrix_exp`` of the twist ``[[hat(omega), rho], [0, 0]]``."""
    return make_pose(*se3_exp_rt(xi))


def se3_exp_rt(xi: Tensor) -> tuple[Tensor, Tensor]:
    """:func:`se3_exp` as R (..., 3, 3) and t (..., 3) in metres, without assembling the pose."""
    check_shape(xi, (6,), "xi")
    rho, omega = xi[..., :3], xi[..., 3:]
    t = (so3_left_jacobian(omega) @ rho[..., None])[..., 0]
    return so3_exp(omega), t


def se3_log(T: Tensor) -> Tensor:
    """Logarithm map SE(3) -> se(3), (..., 4, 4) -> (..., 6) ``(rho, omega)``, angle in [0, pi]."""
    check_shape(T, (4, 4), "T")
    omega = so3_log(T[..., :3, :3])
    rho = (so3_left_jacobian_inv(omega) @ T[..., :3, 3:])[..., 0]
    return torch.cat((rho, omega), dim=-1)


# --------------------------------------------------------------------------------------------------
# Rotation parameterisations
# --------------------------------------------------------------------------------------------------


def euler_to_matrix(angles: Tensor) -> Tensor:
    """``(yaw, pitch, roll)`` radians (any real values) to rotation matrices, (..., 3) -> (..., 3, 3)."""
    check_shape(angles, (3,), "angles")
    return roma.euler_to_rotmat(EULER_CONVENTION, angles)


def matrix_to_euler(R: Tensor) -> Tensor:
    """Rotation matrices to ``(yaw, pitch, roll)``, (..., 3, 3) -> (..., 3): yaw, roll in [-pi, pi],
    pitch in [-pi/2, pi/2] (at gimbal lock, roll is 0)."""
    check_shape(R, (3, 3), "R")
    return roma.rotmat_to_euler(EULER_CONVENTION, R)


def quat_normalize(q: Tensor, eps: float = 1e-8) -> Tensor:
    """Unit quaternions from raw outputs of any norm, (..., 4) -> (..., 4); the identity (with zero
    gradient) where ``|q| < eps``: a zero output carries no rotation. NaN stays NaN."""
    check_shape(q, (4,), "q")
    norm = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    identity = torch.zeros_like(q)
    identity[..., 0] = 1.0
    return torch.where(norm < eps, identity, q / norm.clamp_min(eps))


def quat_to_matrix(q: Tensor) -> Tensor:
    """Unit quaternions ``(w, x, y, z)`` to rotation matrices, (..., 4) -> (..., 3, 3), not normalised."""
    check_shape(q, (4,), "q")
    return roma.unitquat_to_rotmat(roma.quat_wxyz_to_xyzw(q))


def matrix_to_quat(R: Tensor) -> Tensor:
    """Rotation matrices to canonical unit quaternions ``(w, x, y, z)``, (..., 3, 3) -> (..., 4)."""
    check_shape(R, (3, 3), "R")
    q = roma.quat_xyzw_to_wxyz(roma.rotmat_to_unitquat(R))
    return torch.where(q[..., :1] < 0, -q, q)


def sixd_to_matrix(x: Tensor, eps: float = 1e-12) -> Tensor:
    """Two columns ``(c1, c2)`` of any norms to rotation matrices by Gram-Schmidt (Zhou et al. 2019),
    (..., 6) -> (..., 3, 3); ``eps`` keeps gradients finite for zero or parallel columns."""
    check_shape(x, (6,), "x")
    return roma.special_gramschmidt(torch.stack((x[..., :3], x[..., 3:]), dim=-1), epsilon=eps)


def matrix_to_sixd(R: Tensor) -> Tensor:
    """Rotation matrices to their first two columns ``(c1, c2)``, (..., 3, 3) -> (..., 6)."""
    check_shape(R, (3, 3), "R")
    return torch.cat((R[..., :, 0], R[..., :, 1]), dim=-1)


def orthonormalize(R: Tensor) -> Tensor:
    """The nearest rotation matrices (special Procrustes), (..., 3, 3) -> (..., 3, 3)."""
    check_shape(R, (3, 3), "R")
    return roma.special_procrustes(R)


# --------------------------------------------------------------------------------------------------
# Translations
# --------------------------------------------------------------------------------------------------


def scale_to_length(t: Tensor, length: Tensor) -> Tensor:
    """Translations (..., 3) rescaled to lengths (...), ``t / |t| * length``, in the promoted dtype.

    A zero vector becomes ``length`` straight ahead (+z), the ORB+E baseline's rule; values and
    gradients are finite everywhere (zero gradient at ``t = 0``).
    """
    check_shape(t, (3,), "t")
    dtype = torch.promote_types(t.dtype, length.dtype)
    t, length = t.to(dtype), length.to(dtype)
    squared = t.square().sum(-1, keepdim=True)
    moving = squared > 0
    unit = t / torch.sqrt(squared.clamp_min(torch.finfo(dtype).tiny))  # no 0/0, also in the backward
    ahead = torch.zeros_like(unit)
    ahead[..., 2] = 1.0
    return torch.where(moving, unit, ahead) * length[..., None]


# --------------------------------------------------------------------------------------------------
# 4x4 poses
# --------------------------------------------------------------------------------------------------


def make_pose(R: Tensor, t: Tensor) -> Tensor:
    """Poses ``[[R, t], [0, 1]]`` (..., 4, 4) from R (..., 3, 3) and t (..., 3)."""
    check_shape(R, (3, 3), "R")
    check_shape(t, (3,), "t")
    top = torch.cat((R, t[..., None]), dim=-1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1.0
    return torch.cat((top, bottom), dim=-2)


def pose_inverse(T: Tensor) -> Tensor:
    """Rigid inverses ``[[R^T, -R^T t], [0, 1]]``, (..., 4, 4) -> (..., 4, 4)."""
    check_shape(T, (4, 4), "T")
    Rt = T[..., :3, :3].transpose(-1, -2)
    return make_pose(Rt, -(Rt @ T[..., :3, 3:])[..., 0])


def relative_pose(T_a: Tensor, T_b: Tensor) -> Tensor:
    """Frame b seen from frame a, ``inv(T_a) @ T_b``, of (..., 4, 4) poses; computed in float64,
    returned in the inputs' promoted dtype."""
    check_shape(T_a, (4, 4), "T_a")
    check_shape(T_b, (4, 4), "T_b")
    out_dtype = torch.promote_types(T_a.dtype, T_b.dtype)
    return (pose_inverse(T_a.double()) @ T_b.double()).to(out_dtype)


def consecutive_relative_poses(T_w: Tensor) -> Tensor:
    """``inv(T_w[k]) @ T_w[k+1]`` of a sequence's poses, (..., N, 4, 4) -> (..., N-1, 4, 4), in float64
    and returned in ``T_w``'s dtype."""
    check_shape(T_w, (4, 4), "T_w")
    if T_w.dim() < 3:
        raise ValueError(f"T_w must have shape (..., N, 4, 4), got {tuple(T_w.shape)}")
    return relative_pose(T_w[..., :-1, :, :], T_w[..., 1:, :, :])
