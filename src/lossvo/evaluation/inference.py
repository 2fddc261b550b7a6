"""Inference over whole sequences: every consecutive frame pair of a sequence through a trained network,
exactly once, in the windows of :func:`lossvo.data.windows.tile`."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, cast

import numpy as np
import torch
from torch import Tensor, nn

from lossvo.data.windows import tile

if TYPE_CHECKING:
    from lossvo.models import DeepVO, LSTMState


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
        module: a :class:`lossvo.training.module.VOModule` (or anything with
            ``forward(frames (B, L, 3, H, W)) -> (B, L-1, dim)`` and ``decode(outputs) -> (..., 4, 4)``).
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
