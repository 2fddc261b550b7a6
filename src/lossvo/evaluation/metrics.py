"""Trajectory metrics equal to evo's APE / RPE and the KITTI odometry error: functions and torchmetrics.

Float64, vectorised, on the input's device. Poses are (N, 4, 4) camera-to-world ``T_w_c``; units m and rad
(KITTI: per metre). The definitions, and how they are checked against evo and the devkit: docs/metrics.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor
from torchmetrics import Metric
from torchmetrics.utilities import dim_zero_cat

from lossvo import geometry
from lossvo.checks import is_integer, is_number
from lossvo.console import UserError
from lossvo.evaluation.trajectories import integrate, scale_steps

AlignMode = Literal["none", "se3", "sim3", "scale"]
ALIGN_MODES: tuple[str, ...] = ("none", "se3", "sim3", "scale")
KITTI_LENGTHS: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
"""Segment lengths (m) of the KITTI odometry benchmark."""
KITTI_STEP = 10
"""Frames between the first frames of KITTI segments (the devkit's ``step_size``)."""

STATISTICS: tuple[str, ...] = ("rmse", "mean", "median", "std", "min", "max")


def _as_poses(x: Tensor | np.ndarray | Sequence, name: str, device: torch.device | None = None) -> Tensor:
    """``x`` as a float64 (N, 4, 4) tensor; UserError for another shape or a non-finite pose."""
    t = torch.as_tensor(x, dtype=torch.float64, device=device)
    if t.dim() != 3 or tuple(t.shape[1:]) != (4, 4):
        raise UserError(f"{name} must have shape (N, 4, 4), got {tuple(t.shape)}")
    bad = ~torch.isfinite(t).flatten(1).all(dim=1)
    if bool(bad.any()):
        index = int(torch.nonzero(bad)[0, 0])
        raise UserError(f"{name} pose {index} is not finite (NaN or inf)")
    return t


def _check_pair(est: Any, ref: Any, min_poses: int) -> tuple[Tensor, Tensor]:
    """Both trajectories as float64 tensors on est's device, of equal length >= ``min_poses``."""
    est = _as_poses(est, "est")
    ref = _as_poses(ref, "ref", device=est.device)
    if len(est) != len(ref):
        raise UserError(f"trajectories differ in length: est has {len(est)} poses, ref has {len(ref)}")
    if len(est) < min_poses:
        raise UserError(f"need at least {min_poses} poses, got {len(est)}")
    return est, ref


def umeyama(x: Tensor, y: Tensor, with_scale: bool) -> tuple[Tensor, Tensor, Tensor]:
    """Least-squares ``(r, t, c)`` minimising ``sum |y_i - (c r x_i + t)|^2`` (Umeyama 1991).

    x, y: (N, 3) points (m), N >= 3; returns r (3, 3), t (3,), c () (1 without ``with_scale``). Written out,
    not ``roma.rigid_points_registration``, to round and fail on degenerate input step by step as evo's
    ``geometry.umeyama_alignment``.
    """
    n = x.shape[0]
    mean_x, mean_y = x.mean(dim=0), y.mean(dim=0)
    xc, yc = x - mean_x, y - mean_y
    if not bool(xc.any()) or not bool(yc.any()):
        raise UserError("degenerate alignment: all positions identical")
    sigma_x = (xc * xc).sum() / n
    cov = yc.T @ xc / n
    u, d, v = torch.linalg.svd(cov)
    if int((d > torch.finfo(d.dtype).eps).sum()) < 2:
        raise UserError("degenerate alignment: positions are collinear (covariance rank < 2)")
    s = torch.ones(3, dtype=x.dtype, device=x.device)
    if float(torch.linalg.det(u) * torch.linalg.det(v)) < 0.0:
        s[2] = -1.0
    r = u @ torch.diag(s) @ v
    c = (d * s).sum() / sigma_x if with_scale else torch.ones((), dtype=x.dtype, device=x.device)
    t = mean_y - c * (r @ mean_x)
    return r, t, c


def check_align(mode: str) -> None:
    """One line naming an alignment that is not one of :data:`ALIGN_MODES`."""
    if mode not in ALIGN_MODES:
        raise UserError(f"unknown alignment {mode!r}; expected one of {', '.join(ALIGN_MODES)}")


def align(est: Tensor, ref: Tensor, mode: AlignMode = "none") -> Tensor:
    """(N, 4, 4) float64 estimate aligned onto the reference as evo's ``traj_est.align(traj_ref, ...)``.

    ``mode``: "se3" is evo's ``--align``, "sim3" ``--align --correct_scale``, "scale" ``--correct_scale``.
    """
    check_align(mode)
    est, ref = _check_pair(est, ref, 1 if mode == "none" else 3)
    if mode == "none":
        return est
    r, t, c = umeyama(est[:, :3, 3], ref[:, :3, 3], with_scale=mode != "se3")
    out = est.clone()
    if mode in ("sim3", "scale"):
        out[:, :3, 3] = c * out[:, :3, 3]
    if mode in ("se3", "sim3"):
        out = geometry.make_pose(r, t) @ out
    return out


def ape_errors(est: Tensor, ref: Tensor, align: AlignMode = "none") -> tuple[Tensor, Tensor]:
    """evo's APE of (N, 4, 4) poses (N >= 2) after :func:`align`: trans (N,) m, rot (N,) rad."""
    est, ref = _check_pair(est, ref, 2)
    est = _align(est, ref, align)
    trans = torch.linalg.vector_norm(est[:, :3, 3] - ref[:, :3, 3], dim=-1)
    rot = geometry.rotation_angle(est[:, :3, :3].transpose(-1, -2) @ ref[:, :3, :3])
    return trans, rot


def _align(est: Tensor, ref: Tensor, mode: AlignMode) -> Tensor:
    return est if mode == "none" else align(est, ref, mode)


PairsFrom = Literal["estimate", "reference"]
PAIRS_FROM: tuple[PairsFrom, ...] = ("estimate", "reference")


def rpe_pairs_by_path(poses: Tensor, delta_m: float) -> tuple[Tensor, Tensor]:
    """Index pairs i (M,), j (M,) int64 of evo's RPE in metres of ``poses``' path (evo >= 1.31's
    ``filter_pairs_by_path``, ``all_pairs=False``)."""
    steps = torch.linalg.vector_norm(poses[1:, :3, 3] - poses[:-1, :3, 3], dim=-1).double().cpu().numpy()
    travelled = np.concatenate(([0.0], np.cumsum(steps)))
    taken, here = [0], 0
    while (nxt := int(np.searchsorted(travelled, travelled[here] + delta_m, side="left"))) < len(travelled):
        taken.append(nxt)
        here = nxt
    ids = torch.tensor(taken, dtype=torch.int64)
    return ids[:-1], ids[1:]


def rpe_errors(
    est: Tensor,
    ref: Tensor,
    delta: float = 1,
    align: AlignMode = "none",
    delta_unit: str = "f",
    pairs_from: PairsFrom = "estimate",
) -> tuple[Tensor, Tensor]:
    """evo's RPE (consecutive pairs) of (N, 4, 4) poses after :func:`align`: trans (M,) m, rot (M,) rad.

    ``delta``: frames (``delta_unit="f"``) or metres of path (``"m"``) between a pair's poses;
    ``pairs_from``: whose path decides metre-based pairs, the aligned estimate's (evo's default) or the
    reference's (evo's ``pairs_from_reference``).
    """
    est, ref = _check_pair(est, ref, 2)
    est = _align(est, ref, align)
    i, j = _rpe_pairs(est, ref, delta, delta_unit, pairs_from)
    i, j = i.to(est.device), j.to(est.device)
    ref_rel = geometry.pose_inverse(ref[i]) @ ref[j]
    est_rel = geometry.pose_inverse(est[i]) @ est[j]
    E = geometry.pose_inverse(ref_rel) @ est_rel
    return torch.linalg.vector_norm(E[:, :3, 3], dim=-1), geometry.rotation_angle(E[:, :3, :3])


def is_rpe_delta(delta: object, delta_unit: str = "f") -> bool:
    """Whether ``delta`` is an RPE delta: an integer >= 1 in frames (``"f"``), a finite distance > 0 in
    metres (``"m"``)."""
    if delta_unit == "f":
        return is_integer(delta, 1)
    return is_number(delta) and math.isfinite(delta) and delta > 0


def check_rpe_settings(delta: float, delta_unit: str, pairs_from: str) -> None:
    """One line naming the setting that is not a valid RPE delta, unit or pair source."""
    if delta_unit not in ("f", "m"):
        raise UserError(f"delta_unit must be 'f' (frames) or 'm' (metres), got {delta_unit!r}")
    if pairs_from not in PAIRS_FROM:
        raise UserError(f"pairs_from must be one of {', '.join(PAIRS_FROM)}, got {pairs_from!r}")
    if not is_rpe_delta(delta, delta_unit):
        what = "integer number of frames" if delta_unit == "f" else "path distance in metres"
        raise UserError(f"delta must be a positive {what}, got {delta!r}")


def _rpe_pairs(
    est: Tensor, ref: Tensor, delta: float, delta_unit: str, pairs_from: PairsFrom
) -> tuple[Tensor, Tensor]:
    check_rpe_settings(delta, delta_unit, pairs_from)
    if delta_unit == "f":
        if len(est) <= delta:
            raise UserError(f"delta = {delta} frames needs more than {delta} poses, got {len(est)}")
        starts = torch.arange(0, len(est), int(delta))
        return starts[:-1], starts[1:]
    i, j = rpe_pairs_by_path(ref if pairs_from == "reference" else est, float(delta))
    if len(i) == 0:
        raise UserError(f"delta = {delta} m: the {pairs_from}'s path is too short for one pair")
    return i, j


def statistics(errors: Tensor) -> dict[str, float]:
    """evo's statistics of (M,) errors, M >= 1 (:data:`STATISTICS`; population std, numpy's median)."""
    e = torch.as_tensor(errors, dtype=torch.float64).flatten()
    if e.numel() == 0:
        raise UserError("no errors to summarise")
    s = torch.sort(e).values
    m = e.numel()
    median = 0.5 * (s[(m - 1) // 2] + s[m // 2])
    return {
        "rmse": math.sqrt(float((e * e).mean())),
        "mean": float(e.mean()),
        "median": float(median),
        "std": float(e.std(correction=0)) if m > 1 else 0.0,
        "min": float(s[0]),
        "max": float(s[-1]),
    }


def pose_statistics(trans: Tensor, rot: Tensor) -> dict[str, dict[str, float]]:
    """``{"trans": statistics (m), "rot_rad": statistics (rad)}`` of (M,) translation and rotation errors."""
    return {"trans": statistics(trans), "rot_rad": statistics(rot)}


def trajectory_distances(poses: Tensor) -> Tensor:
    """(N,) cumulative path length (m) at each of (N, 4, 4) poses, from 0 (devkit ``trajectoryDistances``)."""
    steps = torch.linalg.vector_norm(poses[1:, :3, 3] - poses[:-1, :3, 3], dim=-1)
    return torch.cat((steps.new_zeros(1), torch.cumsum(steps, dim=0)))


def kitti_segment_errors(est: Tensor, ref: Tensor) -> tuple[Tensor, Tensor]:
    """The KITTI devkit's per-segment errors (``calcSequenceErrors``) of (N, 4, 4) poses.

    Returns t_err (S,) m/m and r_err (S,) rad/m, ordered by first frame, then length (S may be 0). The
    devkit's general inverse and arccos, so that 7-digit pose files score as the devkit's formulas.
    """
    est, ref = _check_pair(est, ref, 2)
    dist = trajectory_distances(ref)
    lens = torch.as_tensor(KITTI_LENGTHS, dtype=torch.float64, device=est.device)
    first = torch.arange(0, len(ref), KITTI_STEP, device=est.device)
    last = torch.searchsorted(dist, dist[first][:, None] + lens[None, :], right=True)
    valid = last < len(ref)
    f = first[:, None].expand_as(last)[valid]
    ln = lens[None, :].expand_as(last)[valid]
    last = last[valid]
    inv = torch.linalg.inv  # the devkit's general inverse: the files' rotations may not be orthonormal
    ref_rel = inv(ref[f]) @ ref[last]
    est_rel = inv(est[f]) @ est[last]
    E = inv(est_rel) @ ref_rel
    t_err = torch.linalg.vector_norm(E[:, :3, 3], dim=-1) / ln
    r_err = devkit_rotation_error(E[:, :3, :3]) / ln
    return t_err, r_err


def devkit_rotation_error(R: Tensor) -> Tensor:
    """The KITTI devkit's ``rotationError`` of (..., 3, 3) matrices: (...,) float64 rad (evaluation only:
    arccos loses precision near 0; training uses :func:`lossvo.geometry.rotation_angle`)."""
    d = 0.5 * (R.to(torch.float64).diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0)
    return torch.acos(d.clamp(-1.0, 1.0))


def _kitti_summary(t_sum: float, r_sum: float, count: int) -> dict[str, float | None]:
    """Mean segment errors as the devkit reports them: t in %, r in deg per 100 m; None without segments."""
    if count == 0:
        return {"t_err_pct": None, "r_err_deg_per_100m": None}
    return {
        "t_err_pct": 100.0 * t_sum / count,
        "r_err_deg_per_100m": 100.0 * math.degrees(r_sum / count),
    }


class _PoseErrorMetric(Metric):
    """Per-pose (or per-pair) translation and rotation ``errors(est, ref)`` of every update, concatenated
    across processes; ``compute`` is :func:`pose_statistics` over them all."""

    is_differentiable = False
    higher_is_better = False
    full_state_update = False
    trans: list[Tensor]  # states (add_state), which nn.Module's __getattr__ would type Tensor | Module
    rot: list[Tensor]

    def __init__(self, errors: Callable[[Tensor, Tensor], tuple[Tensor, Tensor]], **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.errors = errors
        self.add_state("trans", default=[], dist_reduce_fx="cat")
        self.add_state("rot", default=[], dist_reduce_fx="cat")

    def update(self, est: Tensor, ref: Tensor) -> None:
        """Add one sequence: est, ref (N, 4, 4) whole trajectories (poses, not batches of windows)."""
        trans, rot = self.errors(est, ref)
        self.trans.append(trans)
        self.rot.append(rot)

    def compute(self) -> dict[str, dict[str, float]]:
        return pose_statistics(dim_zero_cat(self.trans), dim_zero_cat(self.rot))


class APE(_PoseErrorMetric):
    """evo's absolute pose error pooled over sequences, each aligned on its own (:func:`ape_errors`)."""

    def __init__(self, align: AlignMode = "none", **kwargs: Any) -> None:
        check_align(align)
        super().__init__(partial(ape_errors, align=align), **kwargs)


class RPE(_PoseErrorMetric):
    """evo's relative pose error pooled over sequences (:func:`rpe_errors`)."""

    def __init__(
        self,
        delta: float = 1,
        align: AlignMode = "none",
        delta_unit: str = "f",
        pairs_from: PairsFrom = "estimate",
        **kwargs: Any,
    ) -> None:
        check_rpe_settings(delta, delta_unit, pairs_from)
        check_align(align)
        errors = partial(rpe_errors, delta=delta, align=align, delta_unit=delta_unit, pairs_from=pairs_from)
        super().__init__(errors, **kwargs)


class KittiOdometryError(Metric):
    """The KITTI odometry error pooled over every segment of every sequence (sum states);
    ``compute`` gives ``{"t_err_pct", "r_err_deg_per_100m"}``, None without a segment."""

    is_differentiable = False
    higher_is_better = False
    full_state_update = False
    t_sum: Tensor  # states (add_state), float64 scalars
    r_sum: Tensor
    count: Tensor

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        zero = torch.zeros((), dtype=torch.float64)
        self.add_state("t_sum", default=zero.clone(), dist_reduce_fx="sum")
        self.add_state("r_sum", default=zero.clone(), dist_reduce_fx="sum")
        self.add_state("count", default=zero.clone(), dist_reduce_fx="sum")

    def update(self, est: Tensor, ref: Tensor) -> None:
        """Add one sequence: est, ref (N, 4, 4) whole trajectories."""
        t, r = kitti_segment_errors(est, ref)
        self.t_sum = self.t_sum + t.sum().to(self.t_sum)
        self.r_sum = self.r_sum + r.sum().to(self.r_sum)
        self.count = self.count + t.numel()

    def compute(self) -> dict[str, float | None]:
        return _kitti_summary(float(self.t_sum), float(self.r_sum), round(float(self.count)))


def evaluate(
    gt: Tensor,
    est: Tensor,
    align: AlignMode = "none",
    delta: float = 1,
    delta_unit: str = "f",
    pairs_from: PairsFrom = "estimate",
) -> dict[str, Any]:
    """APE, RPE (:func:`rpe_errors`' pairs) and the KITTI error of one estimate, JSON-ready:
    ``{"ape": {"trans": {stat: m}, "rot_rad": {stat: rad}}, "rpe": ..., "kitti": {"t_err_pct": %,
    "r_err_deg_per_100m": deg}}`` (KITTI's None when the sequence is too short)."""
    ape = ape_errors(est, gt, align)
    rpe = rpe_errors(est, gt, delta, align, delta_unit, pairs_from)
    t, r = kitti_segment_errors(est, gt)
    return {
        "ape": pose_statistics(*ape),
        "rpe": pose_statistics(*rpe),
        "kitti": _kitti_summary(float(t.sum()), float(r.sum()), t.numel()),
    }


def evaluate_relative(
    relative: Tensor | np.ndarray,
    gt: Tensor | np.ndarray,
    align: AlignMode = "none",
    delta: int = 1,
    pooled: Sequence[Metric] = (),
    pooled_scaled: Sequence[Metric] = (),
) -> tuple[Tensor, dict[str, Any]]:
    """Relative poses -> trajectory -> scores: the one path of validation, evaluation and the baselines.

    The (N-1, 4, 4) steps are chained from ``gt[0]`` and scored against ``gt`` (N, 4, 4) with
    :func:`evaluate`, updating ``pooled``; ``rpe_scaled`` scores them each scaled to the ground-truth step
    length (:func:`lossvo.evaluation.trajectories.scale_steps`), updating ``pooled_scaled``. Returns the
    trajectory (N, 4, 4) float64 and :func:`evaluate`'s dict with ``rpe_scaled``.
    """
    gt_t = torch.as_tensor(gt, dtype=torch.float64)
    relative_t = torch.as_tensor(relative, dtype=torch.float64)
    est = integrate(relative_t, start=gt_t[0])
    for metric in pooled:
        metric.update(est, gt_t)
    scaled = integrate(scale_steps(relative_t, geometry.consecutive_relative_poses(gt_t)), start=gt_t[0])
    for metric in pooled_scaled:
        metric.update(scaled, gt_t)
    rpe_scaled = pose_statistics(*rpe_errors(scaled, gt_t, delta, align))
    return est, evaluate(gt_t, est, align, delta) | {"rpe_scaled": rpe_scaled}
