"""How sequences are cut into windows of frames: the one rule for validation, testing and whole-sequence
inference (:func:`tile`), the training windows (:func:`training_starts`), and batches of windows of one
length (:class:`SameLengthBatches`).

A window of ``L`` frames holds ``L - 1`` consecutive frame pairs.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
from torch.utils.data import BatchSampler, Sampler


def tile(n_frames: int, seq_len: int, gap: np.ndarray | None = None) -> np.ndarray:
    """Windows covering every consecutive frame pair of a sequence exactly once.

    Windows of ``seq_len`` frames overlap by one frame (starts 0, seq_len-1, 2 (seq_len-1), ...); the last
    one is shorter where needed (at least 2 frames). With ``gap``, no window spans a gap: each stretch
    between gaps is tiled on its own and a pair across a gap is a window of its own (2 frames).

    Args:
        n_frames: frames in the sequence (>= 2); seq_len: frames per window (>= 2).
        gap: (n_frames - 1,) bool, the pairs that span a gap (:func:`gaps`); None: none does.
    Returns:
        (M, 2) int64 ``[start, stop)`` frame ranges, in order.
    """
    if n_frames < 2:
        raise ValueError(f"a sequence needs at least 2 frames for one relative pose, got {n_frames}")
    if seq_len < 2:
        raise ValueError(f"seq_len must be >= 2 frames, got {seq_len}")
    cuts = np.flatnonzero(gap) if gap is not None else np.zeros(0, dtype=np.int64)
    pieces, first = [], 0
    for k in cuts.tolist():  # a few gaps a sequence: the stretches between them, then the gap's own pair
        pieces += [_stretch(first, k + 1, seq_len), np.array([[k, k + 2]], dtype=np.int64)]
        first = k + 1
    pieces.append(_stretch(first, n_frames, seq_len))
    return np.concatenate(pieces)


def _stretch(first: int, stop: int, seq_len: int) -> np.ndarray:
    """(M, 2) windows tiling frames [first, stop) (none when fewer than 2 frames)."""
    starts = np.arange(first, stop - 1, seq_len - 1, dtype=np.int64)
    return np.stack((starts, np.minimum(starts + seq_len, stop)), axis=1).reshape(-1, 2)


GAP_FACTOR = 1.5
"""A pair of consecutive frames further apart in time than GAP_FACTOR times the sequence's median frame
interval spans a gap (frames the reader dropped, e.g. where the ground truth has none)."""


def gaps(times: np.ndarray) -> np.ndarray:
    """Which consecutive pairs of a sequence span a gap (:data:`GAP_FACTOR`).

    Args:
        times: (N,) timestamps in seconds, increasing.
    Returns:
        (N - 1,) bool.
    """
    interval = np.diff(np.asarray(times, dtype=np.float64))
    if interval.size == 0:
        return np.zeros(0, dtype=bool)
    return interval > GAP_FACTOR * np.median(interval)


def training_starts(
    n_frames: int, seq_len: int, stride: int, step: int = 1, gap: np.ndarray | None = None
) -> np.ndarray:
    """First frames of the full training windows of a sequence: every ``stride`` frames, each window
    taking every ``step``-th frame (it spans ``step (seq_len - 1) + 1`` frames), none spanning a gap.

    Args:
        gap: (n_frames - 1,) bool, the consecutive pairs that span a gap (:func:`gaps`); None: none does.
    Returns:
        (M,) int64 start frames (empty when the sequence is shorter than one window).
    """
    span = step * (seq_len - 1) + 1
    starts = np.arange(0, max(n_frames - span + 1, 0), stride, dtype=np.int64)
    if gap is None or not np.any(gap):
        return starts
    crossed = np.concatenate(([0], np.cumsum(gap)))  # gaps among the pairs before frame k
    return starts[crossed[starts + span - 1] == crossed[starts]]


class SameLengthBatches(BatchSampler):
    """Batches of at most ``batch_size`` windows of one length, in the order of ``sampler``: the
    windows of :func:`tile` are all ``seq_len`` frames but a sequence's last, so they cannot all be
    stacked into one tensor.

    Args:
        sampler: indices of the windows (e.g. a ``SequentialSampler``; Lightning swaps in a
            ``DistributedSampler`` under DDP). batch_size: windows per batch. drop_last: as BatchSampler.
        lengths: frames of each window, by index.
    """

    def __init__(
        self, sampler: Sampler[int], batch_size: int, drop_last: bool = False, lengths: Sequence[int] = ()
    ) -> None:
        super().__init__(sampler, batch_size, drop_last)
        self.lengths = list(lengths)

    def __iter__(self) -> Iterator[list[int]]:
        open_batches: dict[int, list[int]] = {}
        for index in self.sampler:
            batch = open_batches.setdefault(self.lengths[index], [])
            batch.append(index)
            if len(batch) == self.batch_size:
                yield batch
                open_batches[self.lengths[index]] = []
        if not self.drop_last:
            yield from (batch for batch in open_batches.values() if batch)

    def __len__(self) -> int:
        counts = np.bincount([self.lengths[i] for i in self.sampler]) if self.lengths else np.zeros(0)
        full, rest = np.divmod(counts, self.batch_size)
        return int(full.sum() + (0 if self.drop_last else np.count_nonzero(rest)))
