"""Batched distances on SO(3) and SE(3), with finite gradients at zero distance and near 180 degrees; the
metric axioms each satisfies are checked by :mod:`lossvo.geometry.axioms`."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lossvo.geometry.maps import check_shape

_SQRT2 = math.sqrt(2.0)


def rotation_angle(R: Tensor) -> Tensor:
    """Rotation angles in [0, pi] radians, (..., 3, 3) -> (...), as ``atan2(sin, cos)``.

    ``sin`` from the skew part (``|R - R^T|_F = 2 sqrt(2) sin``), ``cos`` from the trace: accurate to
    rounding and with finite gradients everywhere, 0 and pi included (``roma.rotmat_geodesic_distance``
    uses an arcsine, which has neither near pi).
    """
    check_shape(R, (3, 3), "R")
    sin_2sqrt2 = torch.linalg.matrix_norm(R - R.transpose(-1, -2))
    trace = R.diagonal(dim1=-2, dim2=-1).sum(-1)
    return torch.atan2(sin_2sqrt2, _SQRT2 * (trace - 1.0))


def so3_geodesic_distance(R_a: Tensor, R_b: Tensor) -> Tensor:
    """Geodesic distance ``angle(R_a^T R_b)`` in [0, pi] radians, (..., 3, 3) pairs -> (...)."""
    check_shape(R_a, (3, 3), "R_a")
    check_shape(R_b, (3, 3), "R_b")
    return rotation_angle(R_a.transpose(-1, -2) @ R_b)


def so3_chordal_distance(R_a: Tensor, R_b: Tensor) -> Tensor:
    """Chordal distance ``|R_a - R_b|_F = 2 sqrt(2) sin(angle / 2)``, (..., 3, 3) pairs -> (...)."""
    check_shape(R_a, (3, 3), "R_a")
    check_shape(R_b, (3, 3), "R_b")
    return torch.linalg.matrix_norm(R_a - R_b)


def euler_distance(a: Tensor, b: Tensor) -> Tensor:
    """``|a - b|`` of ``(yaw, pitch, roll)`` vectors in radians, (..., 3) pairs -> (...); not a function
    of the rotations alone (yaw and yaw + 2 pi are one rotation at distance 2 pi)."""
    check_shape(a, (3,), "a")
    check_shape(b, (3,), "b")
    return torch.linalg.vector_norm(a - b, dim=-1)


def quat_distance(q_a: Tensor, q_b: Tensor) -> Tensor:
    """``min(|q_a - q_b|, |q_a + q_b|)`` in [0, sqrt(2)], (..., 4) unit quaternion pairs -> (...)."""
    check_shape(q_a, (4,), "q_a")
    check_shape(q_b, (4,), "q_b")
    return torch.minimum(
        torch.linalg.vector_norm(q_a - q_b, dim=-1), torch.linalg.vector_norm(q_a + q_b, dim=-1)
    )


def quat_distance_squared(q_a: Tensor, q_b: Tensor) -> Tensor:
    """``min(|q_a - q_b|^2, |q_a + q_b|^2)`` in [0, 2], (..., 4) pairs -> (...); smooth at zero, where
    :func:`quat_distance` squared would differentiate a norm."""
    check_shape(q_a, (4,), "q_a")
    check_shape(q_b, (4,), "q_b")
    return torch.minimum((q_a - q_b).square().sum(-1), (q_a + q_b).square().sum(-1))


def se3_chordal_distance(T_a: Tensor, T_b: Tensor, weight: float = 1.0) -> Tensor:
    """``sqrt(|t_a - t_b|^2 + weight |R_a - R_b|_F^2)``, (..., 4, 4) pose pairs -> (...); ``weight = 1``
    gives ``|T_a - T_b|_F``, and the chordal loss is its square with ``weight = k3``."""
    check_shape(T_a, (4, 4), "T_a")
    check_shape(T_b, (4, 4), "T_b")
    if not weight >= 0:
        raise ValueError(f"weight must be >= 0, got {weight}")
    dt = T_a[..., :3, 3] - T_b[..., :3, 3]
    dR = (T_a[..., :3, :3] - T_b[..., :3, :3]).flatten(-2)
    # One vector norm (not sqrt of a sum) so that the gradient at zero distance is finite.
    return torch.linalg.vector_norm(torch.cat((dt, math.sqrt(weight) * dR), dim=-1), dim=-1)
