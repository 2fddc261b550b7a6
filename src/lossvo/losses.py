"""Pose losses, one class per parameterisation of the network's relative-pose output: each owns ``dim``
(the head size), ``decode(pred) -> (..., 4, 4)``, ``encode(pose) -> (..., dim)`` and the loss, per frame
pair ``trans_term + k * rot_term`` averaged over batch and time. Formulas and weights: docs/losses.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import roma
import torch
from torch import Tensor, nn

from lossvo import geometry as g
from lossvo.checks import is_number
from lossvo.console import UserError
from lossvo.weighting import DEFAULT_C, HomoscedasticWeighting, check_k, check_unsquared, learned_from_config

TRANSLATIONS = ("metric", "direction", "cue")
"""The translation terms (``loss.translation``; :meth:`PoseLoss.translation_term`)."""

MIN_STEP_M = 1e-3
"""The shortest step with a direction, in metres: ``translation="direction"`` gives a shorter ground-truth
step no term, and divides a predicted ``t`` by ``max(|t|, MIN_STEP_M)``."""

DIRECTION_WEIGHT_M2 = 1.0
"""The direction term's weight in m^2: the metric term of a 1 m step with the same direction error."""


def _floored_unit(t: Tensor) -> Tensor:
    """(..., 3) ``t / max(|t|, MIN_STEP_M)``, with no 0/0 in the value or the gradient at ``t = 0``."""
    return t / torch.sqrt(t.square().sum(-1, keepdim=True).clamp_min(MIN_STEP_M**2))


class PoseLoss(nn.Module):
    """Base class: shape checks, the shared translation term, the weighting, the yardsticks.

    Output ``[t (3), rotation (dim - 3)]`` unless a subclass overrides :meth:`decode_rt` and :meth:`encode`;
    subclasses set ``dim``, ``small_angle_gain``, ``paper_k``, :attr:`to_matrix` and :attr:`from_matrix`
    and implement :meth:`rotation_term`. The loss runs in float32 (float64 for a float64
    prediction) with autocast off.

    Args:
        k: rotation weight; None: the matched weighting ``100 / small_angle_gain``.
        learned: initial log-variances ``{"s_t": .., "s_r": ..}`` of the learned weighting (k must be None).
        translation: one of :data:`TRANSLATIONS`.
    """

    dim: int
    small_angle_gain: float
    """Rotation term ~ gain * theta^2 for a small rotation error theta (radians)."""
    paper_k: float
    """The study's weight for this loss (or for the study's loss with the same rotation distance)."""
    to_matrix: Callable[[Tensor], Tensor]
    """Rotations (..., 3, 3) of the output's rotation part (..., dim - 3)."""
    from_matrix: Callable[[Tensor], Tensor]
    """The output's rotation part (..., dim - 3) that decodes to ``R`` (..., 3, 3)."""

    def __init__(
        self, k: float | None = None, learned: dict[str, float] | None = None, translation: str = "metric"
    ) -> None:
        super().__init__()
        name = type(self).__name__
        if not isinstance(translation, str) or translation not in TRANSLATIONS:
            expected = ", ".join(TRANSLATIONS)
            raise UserError(f"loss.translation: expected one of {expected}, got {translation!r}")
        self.translation = translation
        self.weighting: HomoscedasticWeighting | None = learned_from_config(learned)
        check_k(k, learned=self.weighting is not None)
        if self.weighting is None and k is None:
            k = DEFAULT_C / self.small_angle_gain  # the matched weighting
        if k is not None and (not is_number(k) or not math.isfinite(k) or k < 0):
            raise UserError(f"loss.k: expected a finite number >= 0 for {name}, got {k!r}")
        self.k = None if k is None else float(k)

    def extra_repr(self) -> str:
        weight = "learned" if self.k is None else f"{self.k:g}"
        return f"dim={self.dim}, k={weight}, translation={self.translation}"

    def output_keys(self) -> tuple[str, ...]:
        """The keys :meth:`forward` returns, in order."""
        learned = tuple(self.weighting.values()) if self.weighting is not None else ()
        return ("loss", "trans_loss", "rot_loss", "trans_err_m", "rot_err_rad", *learned)

    def identity_output(self) -> Tensor:
        """The output (dim,) float32 that decodes to the identity pose (the head's initial bias)."""
        return self.encode(torch.eye(4, dtype=torch.float64)).float()

    # -- parameterisation -------------------------------------------------------------------------

    def decode_rt(self, pred: Tensor) -> tuple[Tensor, Tensor]:
        """Rotation (..., 3, 3) and translation (..., 3, metres) encoded by ``pred`` (..., dim)."""
        return self.to_matrix(pred[..., 3:]), pred[..., :3]

    def encode(self, pose: Tensor) -> Tensor:
        """The network output (..., dim) that decodes to ``pose`` (..., 4, 4)."""
        return torch.cat((pose[..., :3, 3], self.from_matrix(pose[..., :3, :3])), dim=-1)

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        """Unweighted rotation term per pair (...), >= 0, of the raw output ``pred`` (..., dim), the
        rotations decoded from it ``R`` (..., 3, 3) and the targets ``R_target`` (..., 3, 3)."""
        raise NotImplementedError

    def decode(self, pred: Tensor) -> Tensor:
        """Relative poses (..., 4, 4) ``T_k`` (frame k+1 seen from frame k) of network outputs (..., dim)."""
        self._check_pred(pred)
        return g.make_pose(*self.decode_rt(pred))

    # -- loss -------------------------------------------------------------------------------------

    def forward(self, pred: Tensor, target: Tensor, metric: Tensor | None = None) -> dict[str, Tensor]:
        """Loss between network outputs and relative-pose targets.

        Args:
            pred: (B, T, dim) network outputs (any leading dims, matching ``target``'s).
            target: (B, T, 4, 4) relative poses ``inv(T_w_k) @ T_w_{k+1}``.
            metric: (B,) bool, whether each window's platform gives metric scale a cue (read by
                ``translation="cue"`` only; None: every window's does).
        Returns:
            Scalars ``loss``, the unweighted means ``trans_loss`` and ``rot_loss``, and two yardsticks
            without gradient: ``trans_err_m`` (:meth:`translation_term`) and ``rot_err_rad`` (mean
            geodesic angle).
        """
        self._check_pred(pred)
        self._check_target(pred, target)
        if metric is not None and (metric.dim() != 1 or pred.dim() < 2 or len(metric) != pred.shape[0]):
            raise ValueError(
                f"metric: expected shape ({pred.shape[0]},), one flag a window, got {tuple(metric.shape)}"
            )
        dtype = torch.promote_types(pred.dtype, torch.float32)
        with torch.autocast(device_type=pred.device.type, enabled=False):
            pred, target = pred.to(dtype), target.to(dtype)
            R_target, t_target = target[..., :3, :3], target[..., :3, 3]
            R, t = self.decode_rt(pred)
            trans, trans_err = self.translation_term(t, t_target, metric)
            rot = self.rotation_term(pred, R, R_target)
            with torch.no_grad():
                rot_err = g.so3_geodesic_distance(R_target, R).mean()
            trans_loss, rot_loss = trans.mean(), rot.mean()
            out = {
                "loss": self.weigh(trans_loss, rot_loss),
                "trans_loss": trans_loss,
                "rot_loss": rot_loss,
                "trans_err_m": trans_err,
                "rot_err_rad": rot_err,
            }
            if self.weighting is not None:
                out.update(self.weighting.values())
            return out

    def translation_term(
        self, t: Tensor, t_target: Tensor, metric: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """The translation term per pair (B, ...) and the yardstick ``trans_err_m`` (its scalar mean
        distance, metres, no gradient) of the decoded and target translations ``t``, ``t_target``
        (B, ..., 3); ``metric`` (B,) bool for ``cue``. Formulas: docs/losses.md."""
        if self.translation == "cue" and metric is not None:
            return self._cue_term(t, t_target, metric)
        if self.translation != "direction":
            trans_sq = (t - t_target).square().sum(-1)
            with torch.no_grad():
                return trans_sq, torch.sqrt(trans_sq).mean()
        step = torch.linalg.vector_norm(t_target, dim=-1)
        unit = _floored_unit(t)
        unit_target = t_target / step.clamp_min(MIN_STEP_M)[..., None]
        moving = step >= MIN_STEP_M  # a standing car has no direction: no translation term
        term = torch.where(moving, (unit - unit_target).square().sum(-1), 0.0) * DIRECTION_WEIGHT_M2
        with torch.no_grad():
            err = torch.linalg.vector_norm(g.scale_to_length(t, step) - t_target, dim=-1).mean()
        return term, err

    @staticmethod
    def _cue_term(t: Tensor, t_target: Tensor, metric: Tensor) -> tuple[Tensor, Tensor]:
        """``cue``: the metric term where ``metric``, elsewhere the scale-given ``|t |t^| / |t| - t^|^2``."""
        metric = metric.to(torch.bool).view(-1, *([1] * (t.dim() - 2)))
        step = torch.linalg.vector_norm(t_target, dim=-1, keepdim=True)
        error = torch.where(metric[..., None], t, _floored_unit(t) * step) - t_target
        term = error.square().sum(-1)
        with torch.no_grad():
            return term, torch.sqrt(term).mean()

    def weigh(self, trans_loss: Tensor, rot_loss: Tensor) -> Tensor:
        """The loss from the unweighted mean terms: ``L_t + k L_r``, or the learned weighting."""
        if self.weighting is not None:
            return self.weighting(trans_loss, rot_loss)
        assert self.k is not None  # __init__ sets k whenever there is no learned weighting
        return trans_loss + self.k * rot_loss

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
    """Euler angles + Euclidean: ``|t - t^|^2 + k |phi - phi^|^2`` (study: k1 = 100); output ``[t (3), yaw,
    pitch, roll]``, ``R = Ry(yaw) Rx(pitch) Rz(roll)``; targets the relative rotation's angles."""

    dim = 6
    small_angle_gain = 1.0  # |dphi|^2 = theta^2 at zero pitch
    paper_k = 100.0
    to_matrix = staticmethod(g.euler_to_matrix)
    from_matrix = staticmethod(g.matrix_to_euler)

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        return (pred[..., 3:] - g.matrix_to_euler(R_target)).square().sum(-1)


class QuaternionLoss(PoseLoss):
    """Quaternion + sign-invariant Euclidean: ``|t - t^|^2 + k min_b |q - b q^|^2`` (study: k2 = 14); output
    ``[t (3), w, x, y, z]``, normalised here. ``squared=False``: the unsquared distance of the study's
    released code (~ theta / 2, no matched k: give ``k``)."""

    dim = 7
    small_angle_gain = 0.25  # |q - q^|^2 = 2 - 2 cos(theta / 2) = theta^2 / 4 + O(theta^4)
    paper_k = 14.0
    from_matrix = staticmethod(g.matrix_to_quat)

    def __init__(
        self,
        k: float | None = None,
        learned: dict[str, float] | None = None,
        squared: bool = True,
        translation: str = "metric",
    ) -> None:
        if not isinstance(squared, bool):
            raise UserError(f"loss.squared: expected true or false, got {squared!r}")
        check_unsquared(squared, k, learned=learned is not None)
        self.squared = squared
        super().__init__(k, learned, translation)

    @staticmethod
    def to_matrix(rot: Tensor) -> Tensor:
        return g.quat_to_matrix(g.quat_normalize(rot))

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        q, q_target = g.quat_normalize(pred[..., 3:]), g.matrix_to_quat(R_target)
        if self.squared:
            return g.quat_distance_squared(q, q_target)
        return g.quat_distance(q, q_target)


class _ChordalTerm(PoseLoss):
    """The chordal rotation term ``|R - R^|_F^2`` of the decoded rotations; ``paper_k`` the chordal k3."""

    small_angle_gain = 2.0  # |R - R^|_F^2 = 8 sin^2(theta / 2) = 2 theta^2 + O(theta^4)
    paper_k = 153.0

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        return g.so3_chordal_distance(R, R_target).square()


class ChordalLoss(_ChordalTerm):
    """SE(3) + chordal: ``|t - t^|^2 + k |R - R^|_F^2`` with ``(R^, t^) = Exp(xi^)`` (study: k3 = 153);
    output the se(3) vector ``xi = (rho, omega)``, the translation ``t^ = V(omega) rho``, not rho."""

    dim = 6

    def decode_rt(self, pred: Tensor) -> tuple[Tensor, Tensor]:
        return g.se3_exp_rt(pred)

    def encode(self, pose: Tensor) -> Tensor:
        return g.se3_log(pose)


class GeodesicLoss(PoseLoss):
    """Rotation vector + geodesic angle: ``|t - t^|^2 + k angle(R, R^)^2``; output ``[t (3), omega (3)]``,
    ``R^ = exp(omega)``; ``paper_k`` the Euler k1."""

    dim = 6
    small_angle_gain = 1.0
    paper_k = 100.0
    to_matrix = staticmethod(g.so3_exp)
    from_matrix = staticmethod(g.so3_log)

    def rotation_term(self, pred: Tensor, R: Tensor, R_target: Tensor) -> Tensor:
        return g.so3_geodesic_distance(R, R_target).square()


class SixDLoss(_ChordalTerm):
    """6-D rotation (two columns, Gram-Schmidt; Zhou et al. 2019) + chordal; output ``[t (3), c1, c2]``."""

    dim = 9
    to_matrix = staticmethod(g.sixd_to_matrix)
    from_matrix = staticmethod(g.matrix_to_sixd)


class SVDLoss(_ChordalTerm):
    """9-D rotation (special Procrustes / SVD) + chordal; output ``[t (3), M (9)]``, M row-major.
    :func:`roma.special_procrustes` (Levinson et al. 2020, Brégier 2021) keeps gradients finite at
    degenerate M."""

    dim = 12

    def to_matrix(self, rot: Tensor) -> Tensor:
        return roma.special_procrustes(rot.unflatten(-1, (3, 3))).to(rot.dtype)

    def from_matrix(self, R: Tensor) -> Tensor:
        return R.flatten(-2)


class SymMatrixQuatLoss(_ChordalTerm):
    """10-D symmetric-matrix quaternion (Peretroukhin et al. 2020) + chordal; output ``[t (3), a (10)]``,
    a symmetric 4x4 A in roma's order (a00, a10, a20, a30, a11, a21, a31, a22, a32, a33), the rotation its
    smallest eigenvalue's eigenvector (:func:`roma.symmatrixvec_to_unitquat`: finite gradients)."""

    dim = 13

    _UPPER = (0, 4, 8, 12, 5, 9, 13, 10, 14, 15)
    """Indices of roma's 10 entries in the row-major flattened 4x4 matrix."""

    def to_matrix(self, rot: Tensor) -> Tensor:
        return roma.unitquat_to_rotmat(roma.symmatrixvec_to_unitquat(rot)).to(rot.dtype)

    def from_matrix(self, R: Tensor) -> Tensor:
        """``A = I - q q^T`` for the quaternion q of ``R``: eigenvalue 0 for q, 1 for the rest."""
        q = roma.rotmat_to_unitquat(R)
        A = torch.eye(4, dtype=q.dtype, device=q.device) - q[..., :, None] * q[..., None, :]
        return A.flatten(-2)[..., list(self._UPPER)]
