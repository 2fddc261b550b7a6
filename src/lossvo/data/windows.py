"""How sequences are cut into windows of frames: the one rule for validation, testing and whole-sequence
inference (:func:`tile`), the training windows (:func:`training_starts`), the dataset of windows of cached
frames (:class:`WindowDataset`), each epoch's order (:class:`EpochShuffle`) and batches of windows of one
length (:class:`SameLengthBatches`).

A window of ``L`` frames holds ``L - 1`` consecutive frame pairs.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import BatchSampler, Dataset, Sampler

from lossvo.data.kitti import relative_targets


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


def training_starts(n_frames: int, seq_len: int, step: int = 1, gap: np.ndarray | None = None) -> np.ndarray:
    """First frames of the full training windows of a sequence: every frame, each window taking every
    ``step``-th frame (it spans ``step (seq_len - 1) + 1`` frames), none spanning a gap.

    Args:
        gap: (n_frames - 1,) bool, the consecutive pairs that span a gap (:func:`gaps`); None: none does.
    Returns:
        (M,) int64 start frames (empty when the sequence is shorter than one window).
    """
    span = step * (seq_len - 1) + 1
    starts = np.arange(max(n_frames - span + 1, 0), dtype=np.int64)
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


class WindowDataset(Dataset):
    """Windows of cached frames with their relative-pose targets.

    Items are dicts: ``frames`` (L, 3, H, W) uint8, ``targets`` (L - 1, 4, 4) float32, ``K`` (3, 3)
    float32, ``metric`` () bool (whether the sequence's platform gives metric scale a cue) and, with flow,
    ``flow`` (L - 1, 2, H, W) float16: a window costs one memory copy. Training
    windows (:func:`lossvo.data.training_starts`) have ``seq_len`` frames, start at every
    frame and exist at each frame step s of ``steps``: every s-th frame, with targets ``inv(T_w_k) @
    T_w_{k+s}`` computed from the poses in float64 (s = 2 doubles the speeds and rotations the network
    sees). Tiled windows (``tiled=True``, validation and test) follow :func:`tile`:
    every consecutive pair exactly once, the last window of a sequence possibly shorter. Conversion to
    float, normalisation and augmentation happen per batch on the training device
    (:meth:`lossvo.data.datamodules.VODataModule.on_after_batch_transfer`), which moves 4x fewer bytes.
    The memory maps are opened lazily in each process (a pickled memmap would be copied whole into every
    DataLoader worker).

    Args:
        cache_files: one cached frame array per sequence; poses: (N_i, 4, 4) T_w_c per sequence.
        seq_len: frames per window; steps: frame steps of the training windows (1: consecutive); tiled:
            tile the sequences instead (steps unused).
        intrinsics: (3, 3) K of each sequence's cached frames (None: the identity).
        flow_files: step -> one cached flow array per sequence (:mod:`lossvo.data.flow`), for every step
            used; None: no flow.
        times: (N_i,) timestamps (s) per sequence: training windows never span a gap in them
            (:func:`gaps`); None: no gaps.
        metric: per sequence, whether its platform gives metric scale a cue (None: every one does).
    """

    def __init__(
        self, cache_files: list[Path], poses: list[np.ndarray], seq_len: int,
        steps: Sequence[int] = (1,), tiled: bool = False, intrinsics: list[np.ndarray] | None = None,
        flow_files: dict[int, list[Path]] | None = None, times: list[np.ndarray] | None = None,
        metric: Sequence[bool] | None = None,
    ) -> None:  # fmt: skip
        self.cache_files = cache_files
        self.flow_files = flow_files
        self.seq_len = seq_len
        Ks = intrinsics if intrinsics is not None else [np.eye(3)] * len(poses)
        self.intrinsics = [torch.from_numpy(np.asarray(K, dtype=np.float32)) for K in Ks]
        flags = [True] * len(poses) if metric is None else list(metric)
        self.metric = [torch.tensor(bool(flag)) for flag in flags]
        steps = (1,) if tiled else tuple(steps)
        self.targets = {
            s: [torch.from_numpy(relative_targets(p, s).astype(np.float32)) for p in poses] for s in steps
        }
        lengths = [len(p) for p in poses]
        gap = [gaps(t) for t in times] if times is not None else [None] * len(poses)
        rows = [
            self._tiles(i, n, seq_len, gap[i]) if tiled else self._training(i, n, seq_len, s, gap[i])
            for s in steps for i, n in enumerate(lengths) if n >= 2
        ]  # fmt: skip
        self.index = np.concatenate(rows) if rows else np.zeros((0, 4), dtype=np.int64)
        self._frames: list[np.ndarray] | None = None
        self._flow: dict[int, list[np.ndarray]] | None = None

    @staticmethod
    def _training(seq: int, n: int, seq_len: int, step: int, gap: np.ndarray | None) -> np.ndarray:
        """(M, 4) rows (sequence, start, stop, step) of a sequence's training windows at one step."""
        starts = training_starts(n, seq_len, step, gap)
        stops = starts + step * (seq_len - 1) + 1
        return np.stack((np.full_like(starts, seq), starts, stops, np.full_like(starts, step)), axis=1)

    @staticmethod
    def _tiles(seq: int, n: int, seq_len: int, gap: np.ndarray | None) -> np.ndarray:
        """(M, 4) rows (sequence, start, stop, 1) of the windows tiling a sequence."""
        ranges = tile(n, seq_len, gap)
        ones = np.ones(len(ranges), dtype=np.int64)
        return np.stack((seq * ones, ranges[:, 0], ranges[:, 1], ones), axis=1)

    @property
    def lengths(self) -> np.ndarray:
        """(M,) frames of each window."""
        return (self.index[:, 2] - self.index[:, 1] - 1) // self.index[:, 3] + 1

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_frames": None, "_flow": None}

    @property
    def frames(self) -> list[np.ndarray]:
        if self._frames is None:
            self._frames = [np.load(f, mmap_mode="r") for f in self.cache_files]
        return self._frames

    def __len__(self) -> int:
        return len(self.index)

    @property
    def flow(self) -> dict[int, list[np.ndarray]]:
        if self._flow is None:
            files = self.flow_files or {}
            self._flow = {step: [np.load(f, mmap_mode="r") for f in paths] for step, paths in files.items()}
        return self._flow

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
    epoch only (Lightning calls :meth:`set_epoch` before every training epoch).

    Args:
        n: dataset size; count: indices per epoch (<= n); seed: the run's seed.
    """

    def __init__(self, n: int, count: int, seed: int) -> None:
        self.n, self.count, self.seed, self.epoch = n, count, seed, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def generator(self) -> torch.Generator:
        """The epoch's own random stream: a function of the seed and the epoch only."""
        state = np.random.SeedSequence([self.seed % 2**63, self.epoch]).generate_state(2, dtype=np.uint32)
        return torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))

    def __iter__(self) -> Iterator[int]:
        return iter(torch.randperm(self.n, generator=self.generator())[: self.count].tolist())

    def __len__(self) -> int:
        return self.count
