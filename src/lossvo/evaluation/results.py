"""A trained network evaluated on whole sequences into its job folder: per sequence its trajectory (KITTI
and TUM, with the ground truth's TUM beside it) and plot, and ``results.json``
(:class:`lossvo.evaluation.job_folder.Results`). Files: docs/training.md.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import torch
from torch import Tensor, nn

from lossvo import geometry
from lossvo.data import layouts
from lossvo.data.kitti import KittiFormatError, pose_path
from lossvo.data.pose_files import write_poses
from lossvo.data.sequence import sequence_names
from lossvo.data.windows import gaps
from lossvo.evaluation import metrics
from lossvo.evaluation.inference import predict_sequence
from lossvo.evaluation.job_folder import (
    MULTI_LAYOUT,
    RESULTS,
    TRANSLATION_SCALED,
    TRANSLATIONS,
    DataRecord,
    LossRecord,
    Overall,
    Results,
    Scores,
    SequenceResult,
    SourceRecord,
)
from lossvo.evaluation.plots import plot_birdseye
from lossvo.evaluation.trajectories import integrate, scale_steps, write_tum

if TYPE_CHECKING:
    from lossvo.data.datamodules import VODataModule
    from lossvo.losses import PoseLoss

log = logging.getLogger("lossvo")

NO_SEGMENT_NOTE = "sequence too short for any KITTI segment (100-800 m): no KITTI error"
NO_GT_NOTE = "no ground truth (no pose file): trajectory starts at identity, no metrics"
NO_METRICS_NOTE = "no sequence with ground truth: no metrics"


def data_record(
    trained: Mapping[str, Any] | None, evaluated: Mapping[str, Any], splits: Mapping[str, Sequence[str]]
) -> DataRecord:
    """The :class:`DataRecord` of an evaluation from datamodule descriptions
    (:meth:`lossvo.data.datamodules.VODataModule.description`): the ``trained`` one its checkpoint records
    (None: the ``evaluated`` one) and the evaluated one with its ``splits``."""
    trained = trained or evaluated
    stats = trained.get("statistics") or {}
    frames = trained.get("frames") or {}
    return DataRecord(
        kind=evaluated.get("_target_"),
        root=str(evaluated["dataset_root"]),
        test=list(splits.get("test", ())),
        unseen=list(splits.get("unseen", ())),
        train_root=trained.get("dataset_root"),
        train=sequence_names((trained.get("splits") or {}).get("train")),
        height=frames.get("height"),
        width=frames.get("width"),
        seq_len=(trained.get("windows") or {}).get("seq_len"),
        normalization=frames.get("normalization"),
        mean=stats.get("mean"),
        std=stats.get("std"),
        **_reading(evaluated, ""),
        **_reading(trained, "train_"),
    )


def _reading(description: Mapping[str, Any], prefix: str) -> dict[str, Any]:
    """How a data description's sequences are read: :class:`DataRecord`'s ``layout``, ``keep_every`` and
    ``sources``, named with ``prefix``."""
    sources = {}
    for name, source in (description.get("sources") or {}).items():
        rendered = source.get("layout") == "synthetic"
        layout = str(source.get("render_layout") or "kitti") if rendered else str(source.get("layout"))
        keep_every = int(source.get("keep_every") or 1)
        sources[name] = SourceRecord(layout, str(source.get("root")), keep_every, rendered)
    one = next(iter(sources.values())) if len(sources) == 1 else None
    return {
        f"{prefix}layout": one.layout if one else MULTI_LAYOUT,
        f"{prefix}keep_every": one.keep_every if one else 1,
        f"{prefix}sources": {} if one else sources,
    }


class PooledScores:
    """APE, RPE and the KITTI error pooled over sequences scored with ``align`` and ``delta`` (frames);
    ``sync``: torchmetrics' ``sync_on_compute`` (False where one process scores every sequence)."""

    def __init__(self, align: metrics.AlignMode = "none", delta: int = 1, sync: bool = True) -> None:
        self.align, self.delta = align, delta
        self.ape = metrics.APE(align=align, sync_on_compute=sync)
        self.rpe = metrics.RPE(delta=delta, align=align, sync_on_compute=sync)
        self.kitti = metrics.KittiOdometryError(sync_on_compute=sync)
        self.rpe_scaled = metrics.RPE(delta=delta, align=align, sync_on_compute=sync)

    def compute(self) -> dict[str, Any] | None:
        """:func:`lossvo.evaluation.metrics.evaluate_relative`'s dict pooled; None before a sequence."""
        if not self.ape.trans:
            return None
        computed = {"ape": self.ape.compute(), "rpe": self.rpe.compute(), "kitti": self.kitti.compute()}
        return computed | {"rpe_scaled": self.rpe_scaled.compute()}


def predict_and_score(
    module: nn.Module,
    datamodule: VODataModule,
    name: str,
    gt: np.ndarray | None,
    pooled: PooledScores,
    carry_state: bool = False,
    device: torch.device | None = None,
    mirror_average: bool = False,
) -> tuple[Tensor, dict[str, Any] | None]:
    """One sequence through the network, chained and scored into ``pooled``: the path validation during
    training and :func:`evaluate_run` share.

    A network trained on the translation's direction has each step scaled to the ground truth's length.
    Without ground truth ``gt`` (N, 4, 4) the trajectory starts at the identity and nothing is scored.
    Returns the trajectory (N, 4, 4) float64 and the sequence's scores (None without ground truth).
    """
    relative = predict_sequence(
        module,
        datamodule.sequence_inputs(name),
        datamodule.prepare,
        datamodule.seq_len,
        carry_state=carry_state,
        mirror_average=mirror_average,
        gap=gaps(datamodule.sequence_times(name)),
    )
    if gt is None:
        return integrate(torch.from_numpy(relative)), None
    gt_t, relative_t = (torch.as_tensor(a, dtype=torch.float64, device=device) for a in (gt, relative))
    if translation_record(module) == TRANSLATION_SCALED:
        relative_t = scale_steps(relative_t, geometry.consecutive_relative_poses(gt_t))
    pooled_metrics = (pooled.ape, pooled.rpe, pooled.kitti)
    return metrics.evaluate_relative(
        relative_t, gt_t, pooled.align, pooled.delta, pooled_metrics, (pooled.rpe_scaled,)
    )


def translation_record(module: nn.Module) -> str:
    """How ``module``'s predicted steps are scored (:data:`TRANSLATIONS` of its loss's ``translation``)."""
    return TRANSLATIONS[cast("PoseLoss", module.loss).translation]


def _ground_truth(datamodule: VODataModule, name: str) -> np.ndarray | None:
    try:
        poses = datamodule.sequence_poses(name)
    except (KittiFormatError, KeyError):
        return None
    return None if poses is None else np.asarray(poses, dtype=np.float64)


def evaluate_run(
    module: nn.Module,
    datamodule: VODataModule,
    out_dir: str | os.PathLike,
    sequences: Sequence[str],
    checkpoint: str | os.PathLike | None = None,
    align: metrics.AlignMode = "none",
    delta: int = 1,
    carry_state: bool = False,
    threads: int | None = None,
    mirror_average: bool = False,
) -> Results:
    """Integrate each sequence with ``module`` (with its ``loss`` and training ``data``) and write its
    trajectories, plots and ``results.json`` into ``out_dir``; ``checkpoint`` and ``threads`` are recorded
    as given."""
    out_dir = Path(out_dir)
    datamodule.setup("test")
    # Evaluation runs in one process (rank 0 of a DDP run): nothing to gather from the others.
    pooled = PooledScores(align, delta, sync=False)
    loss = cast("PoseLoss", module.loss)
    record = LossRecord(type(loss).__name__, loss.k)
    label = f"estimate ({record.name}, k={record.k:g})" if record.k is not None else "estimate"
    translation = translation_record(module)
    per_sequence: dict[str, SequenceResult] = {}
    for name in sequences:
        gt = _ground_truth(datamodule, name)
        est, scores = predict_and_score(
            module, datamodule, name, gt, pooled, carry_state, mirror_average=mirror_average
        )
        scaled = translation == TRANSLATION_SCALED and gt is not None
        legend = f"{label}, steps scaled to the ground truth's" if scaled else label
        files = _write_sequence(out_dir, name, est, gt, datamodule.sequence_times(name), legend)
        if scores is None:
            log.info("sequence %s: %s", name, NO_GT_NOTE)
        else:
            ape, rpe = scores["ape"]["trans"]["rmse"], scores["rpe"]["trans"]["rmse"]
            log.info("sequence %s: APE trans RMSE %.4g m, RPE trans RMSE %.4g m", name, ape, rpe)
        per_sequence[name] = SequenceResult(
            len(est),
            *files[:2],
            ground_truth=_pose_file(datamodule, name, gt) or files[2],
            unseen=name in datamodule.splits["unseen"],
            scores=None if scores is None else _scores(scores),
            note=NO_GT_NOTE if scores is None else None,
            K=datamodule.intrinsics(name).tolist(),
            **_rate(datamodule, name),
        )
    evaluated = [name for name, entry in per_sequence.items() if entry.scores is not None]
    computed = pooled.compute()
    overall = Overall([], note=NO_METRICS_NOTE) if computed is None else Overall(evaluated, _scores(computed))
    result = Results(
        checkpoint=None if checkpoint is None else str(checkpoint),
        loss=record,
        align=align,
        delta=delta,
        seq_len=int(datamodule.seq_len),
        carry_state=carry_state,
        mirror_average=mirror_average,
        threads=threads,
        translation=translation,
        data=data_record(
            cast("dict[str, Any] | None", module.data), datamodule.description(), datamodule.splits
        ),
        sequences=per_sequence,
        overall=overall,
    )
    result.write(out_dir / RESULTS)
    return result


def _rate(datamodule: VODataModule, name: str) -> dict[str, Any]:
    """A sequence's ``rate_hz`` (1 / the median time step), ``rate_from`` and ``metric_scale``."""
    layout = datamodule.sequence_layout(name)
    steps = np.diff(datamodule.sequence_times(name))
    rate = float(1.0 / np.median(steps)) if len(steps) else None
    assumed = layout in layouts.ASSUMED_RATE_HZ
    log.debug(
        "sequence %s: %s frames a second (%s)",
        name,
        f"{rate:.4g}" if rate else "?",
        "assumed: the layout has no timestamps" if assumed else "from its timestamps",
    )
    return {
        "rate_hz": rate,
        "rate_from": "assumed" if assumed else "timestamps",
        "metric_scale": datamodule.metric_scale(name),
    }


def _scores(computed: dict[str, Any]) -> Scores:
    """:func:`lossvo.evaluation.metrics.evaluate`'s dict as :class:`Scores`."""
    scores = Scores.from_json(computed)
    if scores.kitti.t_err_pct is None:
        return replace(scores, kitti=replace(scores.kitti, note=NO_SEGMENT_NOTE))
    return scores


def file_stem(name: str) -> str:
    """A sequence's name as a file name: ``"office/Easy/P000"`` -> ``"office_Easy_P000"``."""
    return name.replace("/", "_")


def _pose_file(datamodule: VODataModule, name: str, gt: np.ndarray | None) -> str | None:
    """The dataset's KITTI pose file of a sequence with ground truth (KITTI layout), else None."""
    if gt is None or [s.reader for s in datamodule.sources.values()] != ["kitti"]:
        return None
    return str(pose_path(datamodule.dataset_root(), name))


def _write_sequence(
    out_dir: Path, name: str, est: Tensor, gt: np.ndarray | None, times: np.ndarray, label: str
) -> tuple[str, str, str | None]:
    """One sequence's trajectory files and plot (``label``: the estimate's legend) in ``out_dir``; returns
    the trajectory's and the plot's paths relative to it and the ``_gt.tum``'s absolute one (or None)."""
    stem = file_stem(name)
    trajectory, plot = f"trajectories/{stem}.txt", f"plots/{stem}.png"
    write_tum(out_dir / f"trajectories/{stem}.tum", times, est)
    gt_file = None
    if gt is not None:
        write_tum(out_dir / f"trajectories/{stem}_gt.tum", times, gt)
        gt_file = str((out_dir / f"trajectories/{stem}_gt.tum").resolve())
    write_poses(out_dir / trajectory, est)
    plot_birdseye(out_dir / plot, gt, {label: est.numpy()}, f"sequence {name}")
    return trajectory, plot, gt_file
