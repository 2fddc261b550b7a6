"""A trained network evaluated on whole sequences: trajectory files, plots and ``results.json``.

:func:`evaluate_run` writes, into a run's folder, per sequence ``trajectories/NN.txt`` (KITTI format,
readable by evo, first pose = ground truth's) and ``plots/NN.png`` (bird's-eye x-z view), and
``results.json``: APE / RPE / KITTI error per sequence and pooled over all, and the data evaluated
(:func:`data_record`), which is all a report needs. ``python -m lossvo.train`` calls it after fitting,
``python -m lossvo.eval`` (:mod:`lossvo.evaluation.eval`) for a checkpoint.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from lossvo.atomic import write_text_atomic
from lossvo.data.kitti import KittiFormatError, pose_path, write_poses
from lossvo.evaluation import metrics
from lossvo.evaluation.inference import predict_sequence
from lossvo.evaluation.plots import plot_birdseye
from lossvo.evaluation.trajectories import integrate

log = logging.getLogger("lossvo")

NO_SEGMENT_NOTE = "sequence too short for any KITTI segment (100-800 m): no KITTI error"
NO_GT_NOTE = "no ground truth (no pose file): trajectory starts at identity, no metrics"


def _ground_truth(datamodule: Any, name: str) -> np.ndarray | None:
    try:
        poses = datamodule.sequence_poses(name)
    except (KittiFormatError, KeyError):
        return None
    return None if poses is None else np.asarray(poses, dtype=np.float64)


def _loss_info(module: nn.Module) -> dict[str, Any]:
    loss = getattr(module, "loss", None)
    return {"class": type(loss).__name__ if loss is not None else None, "k": getattr(loss, "k", None)}


def _kitti_with_note(result: dict[str, Any]) -> dict[str, Any]:
    if result["kitti"]["t_err_pct"] is None:
        result["kitti"]["note"] = NO_SEGMENT_NOTE
    return result


def data_record(module: nn.Module, datamodule: Any) -> dict[str, Any]:
    """``results.json``'s ``data``: the evaluated dataset (``kind``, ``root``, ``test``, ``unseen``), the
    data the network was trained on (``train_root``, ``train``) and its input settings (``height``,
    ``width``, ``seq_len``, ``normalization``, ``mean``, ``std``): what a report needs without
    building a datamodule."""
    here = datamodule.description() if hasattr(datamodule, "description") else {}
    trained = getattr(module, "data", None) or here
    stats = trained.get("statistics") or here.get("statistics") or {}
    return {
        "kind": here.get("_target_"),
        "root": here.get("dataset_root"),
        "test": list(datamodule.splits.get("test", ())) if hasattr(datamodule, "splits") else [],
        "unseen": list(datamodule.splits.get("unseen", ())) if hasattr(datamodule, "splits") else [],
        "train_root": trained.get("dataset_root"),
        "train": list(trained.get("train") or []),
        **{key: trained.get(key, here.get(key)) for key in ("height", "width", "seq_len", "normalization")},
        "mean": stats.get("mean"),
        "std": stats.get("std"),
    }


def _pose_file(datamodule: Any, name: str) -> str | None:
    """The absolute path of a sequence's ground-truth pose file, or None."""
    sequence = getattr(datamodule, "sequences", {}).get(name)
    if sequence is None or sequence.poses is None or not hasattr(datamodule, "dataset_root"):
        return None
    return str(pose_path(datamodule.dataset_root(), name))


def evaluate_run(
    module: nn.Module,
    datamodule: Any,
    out_dir: str | os.PathLike,
    sequences: Sequence[str],
    checkpoint: str | os.PathLike | None = None,
    align: metrics.AlignMode = "none",
    delta: int = 1,
    carry_state: bool = False,
) -> dict[str, Any]:
    """Integrate each sequence with ``module`` and write trajectories, plots and ``results.json``.

    Args:
        module: the trained :class:`lossvo.training.module.VOModule` (on the device to run on).
        datamodule: a set-up-able :class:`lossvo.data.datamodules.KittiDataModule` (``sequence_frames``,
            ``sequence_poses``, ``normalize``, ``seq_len``).
        out_dir: folder receiving ``trajectories/NN.txt``, ``plots/NN.png`` and ``results.json``.
        sequences: sequence names, e.g. ``datamodule.evaluated``.
        checkpoint: the checkpoint the weights came from (recorded in ``results.json``).
        align, delta: APE alignment and RPE delta (:func:`lossvo.evaluation.metrics.evaluate`).
        carry_state: see :func:`predict_sequence`.
    Returns:
        The content of ``results.json``: ``{"checkpoint", "loss": {"class", "k"}, "align", "delta",
        "data": data_record(...), "sequences": {name: {"frames", "trajectory", "plot", "ground_truth",
        "unseen", "ape", "rpe", "kitti"} or a "note"}, "overall": {"sequences", "ape", "rpe", "kitti"}}``.
        A KITTI error is null (with a "note") where no 100 m segment exists.
    """
    out_dir = Path(out_dir)
    datamodule.setup("test")
    # Evaluation runs in one process (rank 0 of a DDP run): nothing to gather from the others.
    pooled = (metrics.APE(align=align, sync_on_compute=False),
              metrics.RPE(delta=delta, align=align, sync_on_compute=False),
              metrics.KittiOdometryError(sync_on_compute=False))  # fmt: skip
    loss = _loss_info(module)
    unseen = set(getattr(datamodule, "splits", {}).get("unseen", ()))
    per_sequence: dict[str, Any] = {}
    for name in sequences:
        relative = predict_sequence(module, datamodule.sequence_frames(name), datamodule.normalize,
                                    datamodule.seq_len, carry_state=carry_state)  # fmt: skip
        entry = _score_sequence(relative, _ground_truth(datamodule, name), name, out_dir, loss, pooled,
                                align, delta)  # fmt: skip
        per_sequence[name] = {**entry, "ground_truth": _pose_file(datamodule, name), "unseen": name in unseen}
    evaluated = [name for name, entry in per_sequence.items() if "ape" in entry]
    overall: dict[str, Any] = {"sequences": [], "note": "no sequence with ground truth: no metrics"}
    if evaluated:
        ape, rpe, kitti = (m.compute() for m in pooled)
        overall = _kitti_with_note({"sequences": evaluated, "ape": ape, "rpe": rpe, "kitti": kitti})
    result = {
        "checkpoint": None if checkpoint is None else str(checkpoint),
        "loss": loss,
        "align": align,
        "delta": delta,
        "seq_len": int(datamodule.seq_len),
        "carry_state": carry_state,
        "data": data_record(module, datamodule),
        "sequences": per_sequence,
        "overall": overall,
    }
    write_text_atomic(out_dir / "results.json", json.dumps(result, indent=2, allow_nan=True) + "\n")
    return result


def _score_sequence(
    relative: np.ndarray, gt: np.ndarray | None, name: str, out_dir: Path, loss: dict[str, Any],
    pooled: Sequence[Any], align: metrics.AlignMode, delta: int,
) -> dict[str, Any]:  # fmt: skip
    """One sequence's trajectory file, plot and scores
    (:func:`lossvo.evaluation.metrics.evaluate_relative`)."""
    entry: dict[str, Any] = {"frames": len(relative) + 1, "trajectory": f"trajectories/{name}.txt",
                             "plot": f"plots/{name}.png"}  # fmt: skip
    if gt is None:
        est = integrate(torch.from_numpy(relative))
        entry["note"] = NO_GT_NOTE
        log.info("sequence %s: %s", name, NO_GT_NOTE)
    else:
        est, scores = metrics.evaluate_relative(relative, gt, align, delta, pooled)
        entry.update(_kitti_with_note(scores))
        log.info("sequence %s: APE trans RMSE %.4g m, RPE trans RMSE %.4g m", name,
                 entry["ape"]["trans"]["rmse"], entry["rpe"]["trans"]["rmse"])  # fmt: skip
    write_poses(out_dir / entry["trajectory"], est)
    label = f"estimate ({loss['class']}, k={loss['k']:g})" if loss["k"] is not None else "estimate"
    plot_birdseye(out_dir / entry["plot"], gt, {label: est.numpy()}, f"sequence {name}")
    return entry
