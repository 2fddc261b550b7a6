"""Evaluation: whole sequences through a trained network, trajectories, plots and ``results.json``.

Command line (Hydra, ``lossvo/conf/eval.yaml``)::

    python -m lossvo.eval ckpt_path=outputs/multirun/<time>/0_loss-euler+seed-0/checkpoints/best.ckpt
    python -m lossvo.eval ckpt_path=... data=kitti data.root=/data/kitti data.test=[09,10]

The checkpoint says how its network was trained (:mod:`lossvo.checkpoints`): frame size, ``seq_len``,
normalisation and its statistics, and the data it was trained on, which is what is evaluated unless
``data=...`` chooses another dataset or ``data.KEY=...`` changes a setting; the other data need hold no
training sequence. An override of the frame size, ``seq_len`` or normalisation that contradicts the
checkpoint is an error. The output folder (``outputs/eval/<time>/``, or ``hydra.run.dir``) receives, per
sequence, ``trajectories/NN.txt`` (KITTI format, readable by evo, first pose = ground truth's),
``plots/NN.png`` (bird's-eye x-z view) and ``results.json`` (APE / RPE / KITTI error per sequence and
pooled over all, and the data evaluated).

From Python: :func:`predict_sequence` (relative poses of one sequence) and :func:`evaluate_run` (all of
the above for a module and a datamodule); ``lossvo.train`` calls the latter after fitting.
"""

from __future__ import annotations

import json
import logging
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import torch
from torch import Tensor, nn

from lossvo import checkpoints, metrics
from lossvo.atomic import atomic_path, write_text_atomic
from lossvo.data.kitti import KittiFormatError, pose_path, write_poses
from lossvo.data.windows import tile
from lossvo.processes import restore_start_method
from lossvo.trajectory import integrate

if TYPE_CHECKING:
    from lossvo.model import DeepVO, LSTMState

log = logging.getLogger("lossvo")

NO_SEGMENT_NOTE = "sequence too short for any KITTI segment (100-800 m): no KITTI error"
NO_GT_NOTE = "no ground truth (no pose file): trajectory starts at identity, no metrics"


# --------------------------------------------------------------------------------------------------
# Inference on whole sequences
# --------------------------------------------------------------------------------------------------


def _device_of(module: nn.Module) -> torch.device:
    device = getattr(module, "device", None)
    if isinstance(device, torch.device):
        return device
    param = next(module.parameters(), None)
    return param.device if param is not None else torch.device("cpu")


def predict_sequence(
    module: nn.Module,
    frames: np.ndarray | Tensor,
    normalize: Callable[[Tensor], Tensor],
    seq_len: int,
    batch_windows: int = 16,
    carry_state: bool = False,
) -> np.ndarray:
    """Relative poses of a whole sequence, every consecutive pair predicted exactly once.

    The sequence is cut into windows as in validation: ``seq_len`` frames overlapping by one
    (:func:`lossvo.data.windows.tile`). By default the LSTM starts from zeros in every window, which is what
    the network saw in training (one window per sample); ``batch_windows`` windows go through the network in
    one forward pass. With ``carry_state=True`` the LSTM state is carried from one window to the next
    (``model.forward_with_state``; the windows then run one after the other): an option for networks trained
    on longer sequences, not what training does.

    The module is put in eval mode (dropout off, BatchNorm running statistics) under ``torch.no_grad``,
    and its previous mode is restored afterwards.

    Args:
        module: a :class:`lossvo.module.VOModule` (or anything with ``forward(frames (B, L, 3, H, W)) ->
            (B, L-1, dim)`` and ``decode(outputs) -> (..., 4, 4)``).
        frames: (N, 3, H, W) uint8 frames (a memory map is read window batch by window batch).
        normalize: uint8 tensor (..., 3, H, W) -> normalised float tensor, e.g. the datamodule's.
        seq_len: frames per window.
        batch_windows: windows per forward pass.
        carry_state: carry the LSTM state across windows.
    Returns:
        (N-1, 4, 4) float64 relative poses ``T_k`` (frame k+1 seen from frame k).
    """
    n = len(frames)
    windows = [(int(a), int(b)) for a, b in tile(n, seq_len)]
    device = _device_of(module)
    was_training = module.training
    module.eval()
    outputs: list[Tensor] = []
    try:
        with torch.no_grad():
            # Duck-typed (a VOModule's): nn.Module's __getattr__ would type these Tensor | Module.
            decode = cast("Callable[[Tensor], Tensor]", module.decode)
            if carry_state:
                model = cast("DeepVO", module.model)
                state: LSTMState | None = None
                for start, stop in windows:
                    x = _load(frames, start, stop, device, normalize)[None]
                    pred, state = model.forward_with_state(x, state)
                    outputs.append(decode(pred)[0].double().cpu())
            else:
                full = [w for w in windows if w[1] - w[0] == seq_len]
                short = [w for w in windows if w[1] - w[0] != seq_len]  # at most the last one
                offsets = torch.arange(seq_len)
                for i in range(0, len(full), batch_windows):
                    group = full[i : i + batch_windows]
                    first, last = group[0][0], group[-1][1]  # consecutive windows: one contiguous read
                    chunk = _load(frames, first, last, device, normalize)
                    index = (torch.tensor([s - first for s, _ in group])[:, None] + offsets).to(device)
                    pred = module(chunk[index])  # (B, seq_len, 3, H, W) -> (B, seq_len - 1, dim)
                    outputs.append(decode(pred).reshape(-1, 4, 4).double().cpu())
                for start, stop in short:
                    pred = module(_load(frames, start, stop, device, normalize)[None])
                    outputs.append(decode(pred)[0].double().cpu())
    finally:
        module.train(was_training)
    relative = torch.cat(outputs)
    if len(relative) != n - 1:  # a bug here would silently shift the whole trajectory
        raise RuntimeError(f"predicted {len(relative)} relative poses for {n} frames (expected {n - 1})")
    return relative.numpy()


def _load(frames: np.ndarray | Tensor, start: int, stop: int, device: torch.device, normalize) -> Tensor:
    chunk = frames[start:stop]
    chunk = chunk if isinstance(chunk, Tensor) else torch.from_numpy(np.array(chunk))  # one copy of the map
    return normalize(chunk.to(device))


# --------------------------------------------------------------------------------------------------
# Evaluation of a run: trajectories, plots, results.json
# --------------------------------------------------------------------------------------------------


def plot_trajectory(path: Path, gt: np.ndarray | None, est: np.ndarray, label: str, title: str) -> None:
    """Bird's-eye view (x right, z forward) of ground truth and estimate, equal axes, as a PNG."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    if gt is not None:
        ax.plot(gt[:, 0, 3], gt[:, 2, 3], color="black", lw=1.5, label="ground truth")
    ax.plot(est[:, 0, 3], est[:, 2, 3], color="tab:red", lw=1.2, label=label)
    ax.plot(est[0, 0, 3], est[0, 2, 3], "o", color="tab:green", ms=5, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight")


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
        module: the trained :class:`lossvo.module.VOModule` (on the device to run on).
        datamodule: a set-up-able :class:`lossvo.data.datamodule.KittiDataModule` (``sequence_frames``,
            ``sequence_poses``, ``normalize``, ``seq_len``).
        out_dir: folder receiving ``trajectories/NN.txt``, ``plots/NN.png`` and ``results.json``.
        sequences: sequence names, e.g. ``datamodule.evaluated``.
        checkpoint: the checkpoint the weights came from (recorded in ``results.json``).
        align, delta: APE alignment and RPE delta (:func:`lossvo.metrics.evaluate`).
        carry_state: see :func:`predict_sequence`.
    Returns:
        The content of ``results.json``: ``{"checkpoint", "loss": {"class", "k"}, "align", "delta",
        "data": data_record(...), "sequences": {name: {"frames", "trajectory", "plot", "ground_truth",
        "unseen", "ape", "rpe", "kitti"} or a "note"}, "overall": {"sequences", "ape", "rpe", "kitti"}}``.
        A KITTI error is null (with a "note") where no 100 m segment exists.
    """
    out_dir = Path(out_dir)
    datamodule.setup("test")
    pooled = (metrics.APE(align=align), metrics.RPE(delta=delta, align=align), metrics.KittiOdometryError())
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
    """One sequence's trajectory file, plot and scores (:func:`lossvo.metrics.evaluate_relative`)."""
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
    plot_trajectory(out_dir / entry["plot"], gt, est.numpy(), label, f"sequence {name}")
    return entry


def _resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def data_overrides(overrides: Sequence[str]) -> tuple[bool, list[str]]:
    """From command-line overrides: whether a data config was chosen (``data=kitti``) and the data keys
    set (``data.root=...`` gives ``root``)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    chosen, keys = False, []
    for override in OverridesParser.create().parse_overrides(list(overrides)):
        key = override.key_or_group
        if key == "data":
            chosen = True
        elif key.startswith("data."):
            keys.append(key.split(".")[1])
    return chosen, list(dict.fromkeys(keys))


def run(cfg: Any, out_dir: Path, overrides: Sequence[str] = ()) -> dict[str, Any]:
    """The body of ``python -m lossvo.eval``: load the checkpoint, build the data it describes (with the
    command line's ``overrides`` of data settings), evaluate the test and unseen-motion sequences."""
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    device = _resolve_device(str(cfg.get("device", "auto")))
    module = checkpoints.load_module(cfg.ckpt_path, device)
    chosen, keys = data_overrides(overrides)
    given = cast("dict[str, Any]", OmegaConf.to_container(cfg.data, resolve=True))
    recorded = checkpoints.recorded_data(cfg.ckpt_path, module)
    explicit = {k: given[k] for k in keys if k in given}
    data_cfg = checkpoints.evaluation_data(recorded, given if chosen else None, explicit)
    datamodule = instantiate(data_cfg, _convert_="all")
    datamodule.prepare_data()
    datamodule.setup("test")
    sequences = list(cfg.sequences) if cfg.get("sequences") else datamodule.evaluated
    sequences = [f"{s:02d}" if isinstance(s, int) else str(s) for s in sequences]
    return evaluate_run(module, datamodule, out_dir, sequences, checkpoint=Path(cfg.ckpt_path).resolve(),
                        align=cfg.get("align", "none"), delta=int(cfg.get("delta", 1)),
                        carry_state=bool(cfg.get("carry_state", False)))  # fmt: skip


def main() -> None:
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from lossvo.train import CONFIG_DIR

    @hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="eval")
    def _main(cfg: Any) -> None:
        restore_start_method()  # a joblib-launched job: let its loader workers start
        out_dir = Path(HydraConfig.get().runtime.output_dir)
        if OmegaConf.is_missing(cfg, "ckpt_path"):
            print("error: ckpt_path is required: python -m lossvo.eval ckpt_path=PATH", file=sys.stderr)
            sys.exit(2)
        try:
            result = run(cfg, out_dir, HydraConfig.get().overrides.task)
        except (FileNotFoundError, ValueError) as e:  # KittiFormatError is a ValueError
            print(f"error: {e}", file=sys.stderr)
            sys.exit(2)
        overall = result["overall"]
        if "ape" in overall:
            names = ", ".join(overall["sequences"])
            ape, rpe = overall["ape"]["trans"]["rmse"], overall["rpe"]["trans"]["rmse"]
            log.info("overall (%s): APE trans RMSE %.4g m, RPE trans RMSE %.4g m", names, ape, rpe)
        log.info("results: %s", out_dir / "results.json")

    _main()


if __name__ == "__main__":
    main()
