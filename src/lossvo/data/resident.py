"""Windows gathered on the training device from a split's arrays copied there once: a batch travels as a
few index arrays (built from the rows of :class:`lossvo.data.windows.WindowDataset`) and is gathered with
one indexing operation per entry, giving the host loader's batch.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor


class ResidentWindows:
    """A :class:`lossvo.data.windows.WindowDataset`'s arrays on one device, and the gather of its batches."""

    def __init__(
        self,
        index: np.ndarray,
        frames: Sequence[np.ndarray],
        targets: dict[int, list[Tensor]],
        intrinsics: Sequence[Tensor],
        metric: Sequence[Tensor],
        flow: dict[int, list[np.ndarray]] | None,
        device: torch.device,
    ) -> None:
        self.index = index
        self.device = device
        self.frames, self.frame_start = _stacked(frames, device)
        steps = sorted(targets)
        self.step_row = {step: row for row, step in enumerate(steps)}  # rows of the (step, sequence) tables
        self.targets, starts = _stacked([t.numpy() for s in steps for t in targets[s]], device)
        self.target_start = starts.reshape(len(steps), -1)
        self.K = torch.stack(list(intrinsics)).to(device)
        self.metric = torch.stack(list(metric)).to(device)
        self.flow: Tensor | None = None
        if flow is not None:  # the same steps as the targets': each step's pairs have their flow
            self.flow, starts = _stacked([f for s in steps for f in flow[s]], device)
            self.flow_start = starts.reshape(len(steps), -1)

    def index_batch(self, windows: Sequence[int]) -> dict[str, Tensor]:
        """The index arrays of a batch of windows of one length L: ``frame_index`` (B, L), ``target_index``
        and ``flow_index`` (B, L-1) int64 rows of the concatenated arrays, ``camera`` (B,) sequences."""
        seq, start, stop, step = self.index[np.asarray(windows, dtype=np.int64)].T
        lengths = (stop - start - 1) // step + 1
        if np.any(lengths != lengths[0]):
            raise ValueError(f"a batch of windows of several lengths: {sorted(set(lengths.tolist()))}")
        offsets = np.arange(lengths[0], dtype=np.int64) * step[:, None]  # (B, L) frames from the start
        row = np.array([self.step_row[int(s)] for s in step], dtype=np.int64)
        pairs = offsets[:, :-1]
        batch = {
            "frame_index": torch.from_numpy((self.frame_start[seq] + start)[:, None] + offsets),
            "target_index": torch.from_numpy((self.target_start[row, seq] + start)[:, None] + pairs),
            "camera": torch.from_numpy(seq.astype(np.int64)),
        }
        if self.flow is not None:
            batch["flow_index"] = torch.from_numpy((self.flow_start[row, seq] + start)[:, None] + pairs)
        return batch

    def gather(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The batch of windows an index batch names, on the device, as the host loader gives it."""
        sequence = batch["camera"].to(self.device, non_blocking=True)
        out = {
            "frames": _take(self.frames, batch["frame_index"]),
            "targets": _take(self.targets, batch["target_index"]),
            "K": self.K.index_select(0, sequence),
            "metric": self.metric.index_select(0, sequence),
        }
        if self.flow is not None:
            out["flow"] = _take(self.flow, batch["flow_index"])
        return out


def _take(array: Tensor, index: Tensor) -> Tensor:
    """Rows ``index`` (B, L) of ``array`` (N, ...) as (B, L, ...)."""
    index = index.to(array.device, non_blocking=True)
    return array.index_select(0, index.flatten()).unflatten(0, tuple(index.shape))


def _stacked(arrays: Sequence[np.ndarray], device: torch.device) -> tuple[Tensor, np.ndarray]:
    """The arrays (N_i, ...) concatenated into one tensor on ``device``, copied one array at a time, and
    (n,) the start of each there."""
    starts = np.concatenate(([0], np.cumsum([len(a) for a in arrays])[:-1])).astype(np.int64)
    dtype = torch.from_numpy(np.zeros(0, dtype=arrays[0].dtype)).dtype
    out = torch.empty((sum(len(a) for a in arrays), *arrays[0].shape[1:]), dtype=dtype, device=device)
    for start, array in zip(starts, arrays, strict=True):
        out[start : start + len(array)].copy_(torch.from_numpy(np.array(array)))
    return out, starts
