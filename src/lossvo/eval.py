"""Evaluation: whole sequences through a trained network, trajectories, plots and ``results.json``.

Command line (Hydra, ``lossvo/conf/eval.yaml``)::

    python -m lossvo.eval ckpt_path=outputs/runs/<time>/checkpoints/best.ckpt
    python -m lossvo.eval ckpt_path=... data=kitti data.root=/data/kitti data.test=[09,10]

The data config must describe the data the checkpoint was trained with (frame size, ``seq_len``, training
split -- it decides the normalisation statistics): pass the same ``data.*`` overrides as for training.
The output folder (``outputs/eval/<time>/``, or ``hydra.run.dir``) receives, per test sequence,
``trajectories/NN.txt`` (KITTI format, readable by evo, first pose = ground truth's), ``plots/NN.png``
(bird's-eye x-z view) and ``results.json`` (APE / RPE / KITTI error per sequence and pooled over all).

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

from lossvo import metrics
from lossvo.atomic import atomic_path, write_text_atomic
from lossvo.data.kitti import KittiFormatError, read_poses, write_poses
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


def window_starts(n_frames: int, seq_len: int) -> list[tuple[int, int]]:
    """(start, stop) frame ranges of the evaluation windows of a sequence of ``n_frames`` frames.

    Windows of ``seq_len`` frames overlap by one frame (starts 0, seq_len-1, 2 (seq_len-1), ...); the last
    one is shorter where needed (at least 2 frames), so every consecutive pair is in exactly one window.
    """
    if n_frames < 2:
        raise ValueError(f"a sequence needs at least 2 frames for one relative pose, got {n_frames}")
    if seq_len < 2:
        raise ValueError(f"seq_len must be >= 2 frames, got {seq_len}")
    step = seq_len - 1
    return [(s, min(s + seq_len, n_frames)) for s in range(0, n_frames - 1, step)]


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

    The sequence is cut into windows as in training and validation: ``seq_len`` frames overlapping by one
    (see :func:`window_starts`). By default the LSTM starts from zeros in every window, which is what the
    network saw in training (one window per sample); ``batch_windows`` windows go through the network in
    one forward pass. With ``carry_state=True`` the LSTM state is carried from one window to the next
    (``model.forward_with_state``; the windows then run one after the other): an option for networks
    trained on longer sequences, not what training does.

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
    windows = window_starts(n, seq_len)
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
        "sequences": {name: {"frames", "trajectory", "plot", "ape", "rpe", "kitti"} or a "note"},
        "overall": {"sequences", "ape", "rpe", "kitti"}}``. Metrics are computed on the trajectory files as
        written; a KITTI error is null (with a "note") where no 100 m segment exists.
    """
    out_dir = Path(out_dir)
    datamodule.setup("test")
    ape, rpe = metrics.APE(align=align), metrics.RPE(delta=delta, align=align)
    kitti = metrics.KittiOdometryError()
    loss = _loss_info(module)
    per_sequence: dict[str, Any] = {}
    evaluated: list[str] = []
    for name in sequences:
        frames = datamodule.sequence_frames(name)
        gt = _ground_truth(datamodule, name)
        relative = predict_sequence(module, frames, datamodule.normalize, datamodule.seq_len,
                                    carry_state=carry_state)  # fmt: skip
        start = None if gt is None else torch.from_numpy(gt[0])
        traj_path = out_dir / "trajectories" / f"{name}.txt"
        write_poses(traj_path, integrate(torch.from_numpy(relative), start=start))
        est = read_poses(traj_path)  # the metrics describe exactly the file a user would evaluate
        plot_path = out_dir / "plots" / f"{name}.png"
        plot_trajectory(plot_path, gt, est, f"estimate ({loss['class']}, k={loss['k']:g})"
                        if loss["k"] is not None else "estimate", f"sequence {name}")  # fmt: skip
        entry: dict[str, Any] = {"frames": len(est), "trajectory": f"trajectories/{name}.txt",
                                 "plot": f"plots/{name}.png"}  # fmt: skip
        if gt is None:
            entry["note"] = NO_GT_NOTE
            log.info("sequence %s: %s", name, NO_GT_NOTE)
        else:
            gt_t, est_t = torch.from_numpy(gt), torch.from_numpy(est)
            entry.update(_kitti_with_note(metrics.evaluate(gt_t, est_t, align, delta)))
            ape.update(est_t, gt_t)
            rpe.update(est_t, gt_t)
            kitti.update(est_t, gt_t)
            evaluated.append(name)
            log.info("sequence %s: APE trans RMSE %.4g m, RPE trans RMSE %.4g m", name,
                     entry["ape"]["trans"]["rmse"], entry["rpe"]["trans"]["rmse"])  # fmt: skip
        per_sequence[name] = entry
    if evaluated:
        overall: dict[str, Any] = {"sequences": evaluated, "ape": ape.compute(), "rpe": rpe.compute(),
                                   "kitti": kitti.compute()}  # fmt: skip
        _kitti_with_note(overall)
    else:
        overall = {"sequences": [], "note": "no sequence with ground truth: no metrics"}
    result = {
        "checkpoint": None if checkpoint is None else str(checkpoint),
        "loss": loss,
        "align": align,
        "delta": delta,
        "seq_len": int(datamodule.seq_len),
        "carry_state": carry_state,
        "sequences": per_sequence,
        "overall": overall,
    }
    write_text_atomic(out_dir / "results.json", json.dumps(result, indent=2, allow_nan=True) + "\n")
    return result


def load_module(ckpt_path: str | os.PathLike, device: str | torch.device = "cpu"):
    """A :class:`lossvo.module.VOModule` from a checkpoint (``weights_only`` loading), on ``device``.

    Raises:
        FileNotFoundError: naming the path, when there is no such file.
    """
    from lossvo.module import VOModule

    path = Path(ckpt_path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        return VOModule.load_from_checkpoint(path, map_location=torch.device(device), weights_only=True)
    except Exception as e:  # a truncated or foreign file: one line naming it, not torch's traceback
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise ValueError(f"{path}: cannot load as a lossvo checkpoint ({type(e).__name__}: {first})") from e


def _resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def check_compatible(module: nn.Module, datamodule: Any) -> None:
    """A clear error when the data's frame size differs from the one the network was built for."""
    model = getattr(module, "model", None)
    expected = (getattr(model, "height", None), getattr(model, "width", None))
    got = (getattr(datamodule, "height", None), getattr(datamodule, "width", None))
    if None not in expected and None not in got and expected != got:
        raise ValueError(
            f"the checkpoint's network expects {expected[0]}x{expected[1]} frames but the data config gives "
            f"{got[0]}x{got[1]}: pass the training run's data overrides (data.height=..., data.width=...)"
        )


def run(cfg: Any, out_dir: Path) -> dict[str, Any]:
    """The body of ``python -m lossvo.eval``: load, build the data, evaluate the test sequences."""
    from hydra.utils import instantiate

    device = _resolve_device(str(cfg.get("device", "auto")))
    module = load_module(cfg.ckpt_path, device)
    datamodule = instantiate(cfg.data)
    check_compatible(module, datamodule)
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
            result = run(cfg, out_dir)
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
