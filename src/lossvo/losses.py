"""Pose losses, one class per parameterisation of the network's relative-pose output.

Each loss owns its parameterisation:

- ``dim``: the size of the network head, one vector per frame pair;
- ``decode(pred) -> (..., 4, 4)``: relative poses, used at inference to chain trajectories;
- ``encode(pose) -> (..., dim)``: the output that decodes to a given pose (for tests and baselines);
- ``forward(pred, target) -> dict``: the loss and its parts.

Per frame pair the loss is ``|t - t^|^2 + k * rot_term``; the translation term is the same squared
Euclidean distance for every loss, so that only the rotation term differs between compared runs.
The result is the mean over all pairs (batch and time). The study sums over time instead; dividing by
the number of pairs keeps ``k`` independent of the window length (multiply by ``T`` to compare).

Besides ``loss``, ``forward`` returns the unweighted means ``trans_loss`` and ``rot_loss`` and two
yardsticks that are the same for every loss, so that runs with different losses can be compared on
one scale: ``trans_err_m`` (mean ``|t - t^|``, metres) and ``rot_err_rad`` (mean geodesic angle between
target and decoded rotation, radians). The yardsticks carry no gradient.

The loss is computed in float32 (float64 if the prediction is float64) with autocast disabled, so
that bf16 mixed precision does not reach the rotation maths. Non-finite predictions give non-finite
losses: nothing here clamps a NaN into a number.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from lossvo import geometry as g


class PoseLoss(nn.Module):
    """Base class: shape checks, the shared translation term, the yardsticks.

    Subclasses set ``dim`` and ``default_k`` and implement :meth:`decode_rt`, :meth:`encode` and
    :meth:`rotation_term`.
    """

    dim: int
    default_k: float

    def __init__(self, k: float | None = None) -> None:
        super().__init__()
        k = self.default_k if k is None else k
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not math.isfinite(k) or k < 0:
            raise ValueError(f"{type(self).__name__}: k must be a finite number >= 0, got {k!r}")
        self.k = float(k)

    def extra_repr(self) -> str:
        return f"dim={self.dim}, k={self.k:g}"

    # -- parameterisation -------------------------------------------------------------------------

    def decode_rt(self, pred: Tensor) -> tuple[Tensor, Tensor]:
        """Rotation (..., 3, 3) and translation (..., 3, metres) encoded by ``pred`` (..., dim)."""
        raise NotImplementedError

    def encode(self, pose: Tensor) -> Tensor:
        """The network output (..., dim) that decodes to ``pose`` (..., 4, 4)."""
        raise NotImplementedError

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        """Unweighted rotation term per pair.

        Args:
            pred: (..., dim) raw network output.
            R: (..., 3, 3) rotations decoded from ``pred``.
            R_target: (..., 3, 3) target rotations.
        Returns:
            (...) non-negative values.
        """
        raise NotImplementedError

    def decode(self, pred: Tensor) -> Tensor:
        """Relative poses encoded by the network output.

        Args:
            pred: (..., dim) network output.
        Returns:
            (..., 4, 4) relative poses ``T_k`` (frame k+1 seen from frame k).
        """
        self._check_pred(pred)
        return g.make_pose(*self.decode_rt(pred))

    # -- loss -------------------------------------------------------------------------------------

    def forward(self, pred: Tensor, target: Tensor) -> dict[str, Tensor]:
        """Loss between network outputs and relative-pose targets.

        Args:
            pred: (B, T, dim) network outputs (any leading dims, matching ``target``'s).
            target: (B, T, 4, 4) relative poses ``inv(T_w_k) @ T_w_{k+1}``.
        Returns:
            Scalar tensors ``loss``, ``trans_loss``, ``rot_loss``, ``trans_err_m``, ``rot_err_rad``.
        """
        self._check_pred(pred)
        self._check_target(pred, target)
        dtype = torch.promote_types(pred.dtype, torch.float32)
        with torch.autocast(device_type=pred.device.type, enabled=False):
            pred, target = pred.to(dtype), target.to(dtype)
            R_target, t_target = target[..., :3, :3], target[..., :3, 3]
            R, t = self.decode_rt(pred)
            trans_sq = (t - t_target).square().sum(-1)
            rot = self.rotation_term(pred, R, R_target)
            with torch.no_grad():
                trans_err = torch.sqrt(trans_sq).mean()
                rot_err = g.so3_geodesic_distance(R_target, R).mean()
            trans_loss, rot_loss = trans_sq.mean(), rot.mean()
            return {
                "loss": trans_loss + self.k * rot_loss,
                "trans_loss": trans_loss,
                "rot_loss": rot_loss,
                "trans_err_m": trans_err,
                "rot_err_rad": rot_err,
            }

    # -- input checks -----------------------------------------------------------------------------

    def _check_pred(self, pred: Tensor) -> None:
        if pred.dim() < 1 or pred.shape[-1] != self.dim:
            raise ValueError(
                f"{type(self).__name__} expects pred of shape (..., {self.dim}), got {tuple(pred.shape)}"
            )

    def _check_target(self, pred: Tensor, target: Tensor) -> None:
        name = type(self).__name__
        if target.dim() < 2 or tuple(target.shape[-2:]) != (4, 4):
            raise ValueError(f"{name} expects target of shape (..., 4, 4), got {tuple(target.shape)}")
        if pred.shape[:-1] != target.shape[:-2]:
            raise ValueError(
                f"{name}: pred {tuple(pred.shape)} and target {tuple(target.shape)} disagree on the "
                f"leading (batch, time) dims: expected target of shape {(*pred.shape[:-1], 4, 4)}"
            )


class EulerLoss(PoseLoss):
    """Euler angles + Euclidean: ``|t - t^|^2 + k |phi - phi^|^2`` (study: k1 = 100).

    Output ``[t (3), yaw, pitch, roll]``, ``R = Ry(yaw) Rx(pitch) Rz(roll)``. Targets are the Euler
    angles of the relative rotation (never differences of absolute angles), in (-pi, pi].
    """

    dim = 6
    default_k = 100.0

    def decode_rt(self, pred: Tensor) -> tuple[Tensor, Tensor]:
        return g.euler_to_matrix(pred[..., 3:]), pred[..., :3]

    def encode(self, pose: Tensor) -> Tensor:
        return torch.cat((pose[..., :3, 3], g.matrix_to_euler(pose[..., :3, :3])), dim=-1)

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        return (pred[..., 3:] - g.matrix_to_euler(R_target)).square().sum(-1)


class QuaternionLoss(PoseLoss):
    """Quaternion + sign-invariant Euclidean: ``|t - t^|^2 + k min_b |q - b q^|^2`` (study: k2 = 14).

    Output ``[t (3), w, x, y, z]`` with a raw quaternion, normalised here (see
    :func:`lossvo.geometry.quat_normalize`); q and -q give identical losses.
    """

    dim = 7
    default_k = 14.0

    def decode_rt(self, pred: Tensor) -> tuple[Tensor, Tensor]:
        return g.quat_to_matrix(g.quat_normalize(pred[..., 3:])), pred[..., :3]

    def encode(self, pose: Tensor) -> Tensor:
        return torch.cat((pose[..., :3, 3], g.matrix_to_quat(pose[..., :3, :3])), dim=-1)

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        return g.quat_distance(g.quat_normalize(pred[..., 3:]), g.matrix_to_quat(R_target)).square()


class ChordalLoss(PoseLoss):
    """SE(3) + chordal: ``|t - t^|^2 + k |R - R^|_F^2`` with ``(R^, t^) = Exp(xi^)`` (study: k3 = 153).

    Output the se(3) vector ``xi = (rho, omega)``; the translation is ``t^ = V(omega) rho``, not rho.
    """

    dim = 6
    default_k = 153.0

    def decode_rt(self, pred: Tensor) -> tuple[Tensor, Tensor]:
        T = g.se3_exp(pred)
        return T[..., :3, :3], T[..., :3, 3]

    def encode(self, pose: Tensor) -> Tensor:
        return g.se3_log(pose)

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        return g.so3_chordal_distance(R, R_target).square()


class GeodesicLoss(PoseLoss):
    """Rotation vector + geodesic angle: ``|t - t^|^2 + k angle(R, R^)^2``.

    Output ``[t (3), omega (3)]``, ``R^ = exp(omega)``. Default k = 100: for small errors the squared
    angle equals the squared Euler error, so this matches the Euler loss's scale.
    """

    dim = 6
    default_k = 100.0

    def decode_rt(self, pred: Tensor) -> tuple[Tensor, Tensor]:
        return g.so3_exp(pred[..., 3:]), pred[..., :3]

    def encode(self, pose: Tensor) -> Tensor:
        return torch.cat((pose[..., :3, 3], g.so3_log(pose[..., :3, :3])), dim=-1)

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        return g.so3_geodesic_distance(R, R_target).square()


class SixDLoss(PoseLoss):
    """6-D rotation (two columns, Gram-Schmidt) + chordal: ``|t - t^|^2 + k |R - R^|_F^2``.

    Output ``[t (3), c1 (3), c2 (3)]``. Default k = 153, the chordal loss's, as the distance is the same.
    """

    dim = 9
    default_k = 153.0

    def decode_rt(self, pred: Tensor) -> tuple[Tensor, Tensor]:
        return g.sixd_to_matrix(pred[..., 3:]), pred[..., :3]

    def encode(self, pose: Tensor) -> Tensor:
        return torch.cat((pose[..., :3, 3], g.matrix_to_sixd(pose[..., :3, :3])), dim=-1)

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        return g.so3_chordal_distance(R, R_target).square()
