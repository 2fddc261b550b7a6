"""Inference over whole sequences: every consecutive frame pair of a sequence through a trained network,
exactly once, in the windows of :func:`lossvo.data.windows.tile`."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, cast

import numpy as np
import roma
import torch
from torch import Tensor, nn

from lossvo.data.transforms import mirror_inputs, mirror_poses
from lossvo.data.windows import tile

if TYPE_CHECKING:
    from lossvo.models import DeepVO, LSTMState


Inputs = Mapping[str, "np.ndarray | Tensor"]
"""A whole sequence's inputs (:meth:`lossvo.data.datamodules.VODataModule.sequence_inputs`): ``frames``
(N, 3, H, W) uint8, optionally ``flow`` (N - 1, 2, H, W) of each consecutive pair and ``K`` (3, 3)."""


def predict_sequence(
    module: nn.Module,
    inputs: Inputs,
    prepare: Callable[[dict[str, Tensor]], dict[str, Tensor]],
    seq_len: int,
    batch_windows: int = 16,
    carry_state: bool = False,
    mirror_average: bool = False,
    gap: np.ndarray | None = None,
) -> np.ndarray:
    """(N-1, 4, 4) float64 relative poses of a whole sequence, every consecutive pair predicted once.

    Windows of ``seq_len`` frames overlap by one, none across a ``gap`` ((N - 1,) bool), ``batch_windows``
    a forward pass; ``carry_state`` carries the LSTM state from one window to the next instead (DeepVO's
    ``forward_with_state``); ``mirror_average`` averages with the mirrored inputs' prediction
    (:func:`average_with_mirror`). ``prepare``: loaded inputs -> what the network reads.
    """
    windows = [(int(a), int(b)) for a, b in tile(len(inputs["frames"]), seq_len, gap)]
    plain = _predict(module, inputs, prepare, windows, batch_windows, carry_state)
    if not mirror_average:
        return plain
    mirrored = _predict(
        module, inputs, lambda x: prepare(mirror_inputs(x)), windows, batch_windows, carry_state
    )
    return average_with_mirror(torch.from_numpy(plain), torch.from_numpy(mirrored)).numpy()


def average_with_mirror(plain: Tensor, mirrored: Tensor) -> Tensor:
    """(..., 4, 4) average of relative poses and those predicted on mirrored inputs, mirrored back: the
    geodesic midpoint of the rotations, the mean of the translations."""
    back = mirror_poses(mirrored)
    Ra, Rb = plain[..., :3, :3], back[..., :3, :3]
    half = roma.rotvec_to_rotmat(roma.rotmat_to_rotvec(Ra.transpose(-1, -2) @ Rb) / 2)
    average = plain.clone()
    average[..., :3, :3] = Ra @ half
    average[..., :3, 3] = (plain[..., :3, 3] + back[..., :3, 3]) / 2
    return average


def _predict(
    module: nn.Module,
    inputs: Inputs,
    prepare: Callable[[dict[str, Tensor]], dict[str, Tensor]],
    windows: list[tuple[int, int]],
    batch_windows: int,
    carry_state: bool,
) -> np.ndarray:
    """:func:`predict_sequence` without mirror averaging, over the given ``[start, stop)`` windows."""
    n = len(inputs["frames"])
    device = next(module.parameters()).device
    was_training = module.training
    module.eval()
    outputs: list[Tensor] = []  # per window, (stop - start - 1, 4, 4), in order
    try:
        with torch.no_grad():
            # Duck-typed (a VOModule's): nn.Module's __getattr__ would type these Tensor | Module.
            decode = cast("Callable[[Tensor], Tensor]", module.decode)
            if carry_state:
                model = cast("DeepVO", module.model)
                state: LSTMState | None = None
                for start, stop in windows:
                    x = prepare(_load(inputs, start, stop, device))["frames"][None]
                    pred, state = model.forward_with_state(x, state)
                    outputs.append(decode(pred)[0].double().cpu())
            else:
                for group in _batches(windows, batch_windows):
                    first, last = group[0][0], group[-1][1]  # one contiguous read
                    chunk = prepare(_load(inputs, first, last, device))
                    batch = _windows(chunk, [start - first for start, _ in group], group[0][1] - first)
                    outputs.extend(decode(module(batch)).double().cpu())  # (B, length - 1, 4, 4)
    finally:
        module.train(was_training)
    relative = torch.cat(outputs)
    if len(relative) != n - 1:  # a bug here would silently shift the whole trajectory
        raise RuntimeError(f"predicted {len(relative)} relative poses for {n} frames (expected {n - 1})")
    return relative.numpy()


def _batches(windows: list[tuple[int, int]], size: int) -> list[list[tuple[int, int]]]:
    """The windows in batches of up to ``size`` of the longest length, each overlapping the one before by
    one frame (one contiguous read); any other window alone."""
    longest = max(stop - start for start, stop in windows)
    batches: list[list[tuple[int, int]]] = []
    for start, stop in windows:
        batch = batches[-1] if batches else []
        joins = 0 < len(batch) < size and batch[-1][1] - 1 == start
        if joins and stop - start == longest == batch[-1][1] - batch[-1][0]:
            batch.append((start, stop))
        else:
            batches.append([(start, stop)])
    return batches


def _tensor(array: np.ndarray | Tensor) -> Tensor:
    return array if isinstance(array, Tensor) else torch.from_numpy(np.array(array))  # one copy of a map


def _load(inputs: Inputs, start: int, stop: int, device: torch.device) -> dict[str, Tensor]:
    """Frames [start, stop) of a sequence with their pairs' flow (start .. stop - 2) and K, on ``device``."""
    parts = {"frames": slice(start, stop), "flow": slice(start, stop - 1), "K": slice(None)}
    return {name: _tensor(inputs[name][part]).to(device) for name, part in parts.items() if name in inputs}


def _windows(chunk: dict[str, Tensor], starts: list[int], length: int) -> dict[str, Tensor]:
    """A batch of windows of ``length`` frames starting at ``starts`` (indices into the chunk's frames)."""
    index = torch.tensor(starts, device=chunk["frames"].device)[:, None] + torch.arange(
        length, device=chunk["frames"].device
    )
    batch = {"frames": chunk["frames"][index]}
    if "flow" in chunk:
        batch["flow"] = chunk["flow"][index[:, :-1]]
    if "K" in chunk:
        batch["K"] = chunk["K"].expand(len(starts), 3, 3)
    return batch
