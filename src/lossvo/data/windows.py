"""How sequences are cut into windows of frames (tiles for validation, testing and inference; training
windows), the dataset of windows of cached frames, each epoch's order and batches of one length.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import BatchSampler, Dataset, Sampler

from lossvo.data.kitti import relative_targets


def tile(n_frames: int, seq_len: int, gap: np.ndarray | None = None) -> np.ndarray:
    """(M, 2) int64 ``[start, stop)`` windows covering every consecutive frame pair exactly once.

    Windows of ``seq_len`` frames overlap by one frame, the last one shorter where needed. ``gap``:
    (n_frames - 1,) bool, the pairs that span a gap: each stretch is tiled on its own, a gap's pair alone.
    """
    if n_frames < 2:
        raise ValueError(f"a sequence needs at least 2 frames for one relative pose, got {n_frames}")
    if seq_len < 2:
        raise ValueError(f"seq_len must be >= 2 frames, got {seq_len}")
    pieces, first = [], 0  # a few gaps a sequence: the stretches between them, then the gap's own pair
    for k in np.flatnonzero([] if gap is None else gap).tolist():
        pieces += [_stretch(first, k + 1, seq_len), np.array([[k, k + 2]], dtype=np.int64)]
        first = k + 1
    pieces.append(_stretch(first, n_frames, seq_len))
    return np.concatenate(pieces)


def _stretch(first: int, stop: int, seq_len: int) -> np.ndarray:
    starts = np.arange(first, stop - 1, seq_len - 1, dtype=np.int64)
    return np.stack((starts, np.minimum(starts + seq_len, stop)), axis=1).reshape(-1, 2)


GAP_FACTOR = 1.5
"""A pair further apart than GAP_FACTOR times the sequence's median frame interval spans a gap."""


def gaps(times: np.ndarray) -> np.ndarray:
    """(N - 1,) bool: which consecutive pairs of (N,) timestamps (s) span a gap (:data:`GAP_FACTOR`)."""
    interval = np.diff(np.asarray(times, dtype=np.float64))
    if interval.size == 0:
        return np.zeros(0, dtype=bool)
    return interval > GAP_FACTOR * np.median(interval)


def training_starts(n_frames: int, seq_len: int, step: int = 1, gap: np.ndarray | None = None) -> np.ndarray:
    """(M,) int64 first frames of a sequence's training windows of every ``step``-th frame, none spanning
    a gap (``gap``: as :func:`tile`'s)."""
    span = step * (seq_len - 1) + 1
    starts = np.arange(max(n_frames - span + 1, 0), dtype=np.int64)
    if gap is None or not np.any(gap):
        return starts
    crossed = np.concatenate(([0], np.cumsum(gap)))  # gaps among the pairs before frame k
    return starts[crossed[starts + span - 1] == crossed[starts]]


class SameLengthBatches(BatchSampler):
    """Batches of at most ``batch_size`` windows of one length (``lengths``: frames of each window), in
    the order of ``sampler``: a sequence's last tile may be shorter than the others."""

    def __init__(self, sampler: Sampler[int], batch_size: int, lengths: Sequence[int]) -> None:
        super().__init__(sampler, batch_size, drop_last=False)
        self.lengths = list(lengths)

    def __iter__(self) -> Iterator[list[int]]:
        open_batches: dict[int, list[int]] = {}
        for index in self.sampler:
            batch = open_batches.setdefault(self.lengths[index], [])
            batch.append(index)
            if len(batch) == self.batch_size:
                yield batch
                open_batches[self.lengths[index]] = []
        yield from (batch for batch in open_batches.values() if batch)

    def __len__(self) -> int:
        return sum(1 for _ in self)


class WindowDataset(Dataset):
    """Windows of cached frames with their relative-pose targets, as rows ``(sequence, start, stop, step)``
    of :attr:`index`: training windows at each frame step of ``steps``, or tiles (``tiled``, steps ``[1]``).

    Items: ``frames`` (L, 3, H, W) uint8, ``targets`` (L - 1, 4, 4) float32, ``K`` (3, 3) float32,
    ``metric`` () bool and, with ``flow_files`` (step -> one file per sequence), ``flow`` (L - 1, 2, H, W)
    float16. The memory maps are opened lazily in each process (a pickled one would be copied whole).
    """

    def __init__(
        self, cache_files: list[Path], poses: list[np.ndarray], seq_len: int, steps: Sequence[int],
        tiled: bool, intrinsics: list[np.ndarray], flow_files: dict[int, list[Path]] | None,
        times: list[np.ndarray], metric: Sequence[bool],
    ) -> None:  # fmt: skip
        self.cache_files = cache_files
        self.flow_files = flow_files
        self.intrinsics = [torch.from_numpy(np.asarray(K, dtype=np.float32)) for K in intrinsics]
        self.metric = [torch.tensor(bool(flag)) for flag in metric]
        self.targets = {
            s: [torch.from_numpy(relative_targets(p, s).astype(np.float32)) for p in poses] for s in steps
        }
        sequences = [(len(p), gaps(t)) for p, t in zip(poses, times, strict=True)]
        rows = [np.zeros((0, 4), dtype=np.int64)]  # (sequence, start, stop, step) of each window
        for s in steps:
            for seq, (n, gap) in enumerate(sequences):
                if n < 2:
                    continue
                if tiled:
                    starts, stops = tile(n, seq_len, gap).T
                else:
                    starts = training_starts(n, seq_len, s, gap)
                    stops = starts + s * (seq_len - 1) + 1
                rows.append(np.stack((np.full_like(starts, seq), starts, stops, np.full_like(starts, s)), 1))
        self.index = np.concatenate(rows)

    @property
    def lengths(self) -> np.ndarray:
        """(M,) frames of each window."""
        return (self.index[:, 2] - self.index[:, 1] - 1) // self.index[:, 3] + 1

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("frames", "flow")}  # opened lazily

    @functools.cached_property
    def frames(self) -> list[np.ndarray]:
        return [np.load(f, mmap_mode="r") for f in self.cache_files]

    @functools.cached_property
    def flow(self) -> dict[int, list[np.ndarray]]:
        return {s: [np.load(f, mmap_mode="r") for f in paths] for s, paths in (self.flow_files or {}).items()}

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        seq, start, stop, step = (int(v) for v in self.index[i])
        item = {
            "frames": torch.from_numpy(np.array(self.frames[seq][start:stop:step])),  # one copy
            "targets": self.targets[step][seq][start : stop - 1 : step],
            "K": self.intrinsics[seq],
            "metric": self.metric[seq],
        }
        if self.flow_files is not None:  # pair (k, k + step) is field k of the step's flow
            item["flow"] = torch.from_numpy(np.array(self.flow[step][seq][start : stop - 1 : step]))
        return item


class EpochShuffle(Sampler[int]):
    """``count`` of ``n`` indices without replacement in a random order that depends on ``seed`` and the
    epoch only (Lightning calls :meth:`set_epoch` before every training epoch)."""

    def __init__(self, n: int, count: int, seed: int) -> None:
        self.n, self.count, self.seed, self.epoch = n, count, seed, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __iter__(self) -> Iterator[int]:
        state = np.random.SeedSequence([self.seed % 2**63, self.epoch]).generate_state(2, dtype=np.uint32)
        generator = torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))  # the epoch's own
        return iter(torch.randperm(self.n, generator=generator)[: self.count].tolist())

    def __len__(self) -> int:
        return self.count
