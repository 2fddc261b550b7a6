"""Batched distances on SO(3) and SE(3): the rotation angle, geodesic and chordal distances, Euler and
quaternion distances, the SE(3) chordal distance.

Every function takes tensors with any leading (batch) dimensions and is safe under autograd (finite
gradients at zero distance and near 180 degrees). Which metric axioms each one satisfies is checked by
:mod:`lossvo.geometry.axioms`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lossvo.geometry.maps import check_shape

_SQRT2 = math.sqrt(2.0)


def rotation_angle(R: Tensor) -> Tensor:
    """Rotation angle in [0, pi] of rotation matrices, ``atan2(sin, cos)``.

    ``sin`` comes from the skew part (``|R - R^T|_F = 2 sqrt(2) sin``) and ``cos`` from the trace, so
    the angle is accurate to rounding everywhere (no arccos floor near 0, no arcsine blow-up near
    pi) and the gradient is finite everywhere, including at 0 and pi.

    Args:
        R: (..., 3, 3) rotation matrices.
    Returns:
        (...) angles in radians.
    """
    check_shape(R, (3, 3), "R")
    sin_2sqrt2 = torch.linalg.matrix_norm(R - R.transpose(-1, -2))
    trace = R.diagonal(dim1=-2, dim2=-1).sum(-1)
    return torch.atan2(sin_2sqrt2, _SQRT2 * (trace - 1.0))


def so3_geodesic_distance(R_a: Tensor, R_b: Tensor) -> Tensor:
    """Geodesic (angular) distance ``angle(R_a^T R_b)`` on SO(3), in [0, pi].

    Args:
        R_a, R_b: (..., 3, 3) rotation matrices.
    Returns:
        (...) angles in radians.
    """
    check_shape(R_a, (3, 3), "R_a")
    check_shape(R_b, (3, 3), "R_b")
    return rotation_angle(R_a.transpose(-1, -2) @ R_b)


def so3_chordal_distance(R_a: Tensor, R_b: Tensor) -> Tensor:
    """Chordal distance ``|R_a - R_b|_F = 2 sqrt(2) sin(angle / 2)``, in [0, 2 sqrt(2)].

    Args:
        R_a, R_b: (..., 3, 3) rotation matrices.
    Returns:
        (...) distances.
    """
    check_shape(R_a, (3, 3), "R_a")
    check_shape(R_b, (3, 3), "R_b")
    return torch.linalg.matrix_norm(R_a - R_b)


def euler_distance(a: Tensor, b: Tensor) -> Tensor:
    """Euclidean distance between Euler-angle vectors, ``|a - b|`` (radians).

    Not a function of the rotations alone: yaw and yaw + 2 pi are one rotation at distance 2 pi.

    Args:
        a, b: (..., 3) ``(yaw, pitch, roll)``.
    Returns:
        (...) distances.
    """
    check_shape(a, (3,), "a")
    check_shape(b, (3,), "b")
    return torch.linalg.vector_norm(a - b, dim=-1)


def quat_distance(q_a: Tensor, q_b: Tensor) -> Tensor:
    """Sign-invariant quaternion distance ``min(|q_a - q_b|, |q_a + q_b|)``, in [0, sqrt(2)].

    Args:
        q_a, q_b: (..., 4) unit quaternions ``(w, x, y, z)``.
    Returns:
        (...) distances; NaN in, NaN out.
    """
    check_shape(q_a, (4,), "q_a")
    check_shape(q_b, (4,), "q_b")
    return torch.minimum(
        torch.linalg.vector_norm(q_a - q_b, dim=-1), torch.linalg.vector_norm(q_a + q_b, dim=-1)
    )


def quat_distance_squared(q_a: Tensor, q_b: Tensor) -> Tensor:
    """Squared sign-invariant quaternion distance ``min(|q_a - q_b|^2, |q_a + q_b|^2)``, in [0, 2].

    Smooth where :func:`quat_distance` squared would differentiate a norm at zero.

    Args:
        q_a, q_b: (..., 4) unit quaternions ``(w, x, y, z)``.
    Returns:
        (...) squared distances.
    """
    check_shape(q_a, (4,), "q_a")
    check_shape(q_b, (4,), "q_b")
    return torch.minimum((q_a - q_b).square().sum(-1), (q_a + q_b).square().sum(-1))


def se3_chordal_distance(T_a: Tensor, T_b: Tensor, weight: float = 1.0) -> Tensor:
    """Chordal distance on SE(3), ``sqrt(|t_a - t_b|^2 + weight |R_a - R_b|_F^2)``.

    With ``weight = 1`` this is the Frobenius norm of ``T_a - T_b``; the chordal loss is its square
    with ``weight = k3``.

    Args:
        T_a, T_b: (..., 4, 4) poses.
        weight: non-negative weight of the rotation part.
    Returns:
        (...) distances.
    """
    check_shape(T_a, (4, 4), "T_a")
    check_shape(T_b, (4, 4), "T_b")
    if not weight >= 0:
        raise ValueError(f"weight must be >= 0, got {weight}")
    dt = T_a[..., :3, 3] - T_b[..., :3, 3]
    dR = (T_a[..., :3, :3] - T_b[..., :3, :3]).flatten(-2)
    # One vector norm (not sqrt of a sum) so that the gradient at zero distance is finite.
    return torch.linalg.vector_norm(torch.cat((dt, math.sqrt(weight) * dR), dim=-1), dim=-1)
