"""The windowing rule: tiles cover every frame pair exactly once; training windows; batches by length."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils.data import SequentialSampler

from helpers import data_module
from lossvo.data import windows
from lossvo.data.kitti import relative_targets


@pytest.mark.parametrize("n", [2, 3, 4, 5, 7, 10, 11, 12, 13, 20, 31])
@pytest.mark.parametrize("seq_len", [2, 3, 4, 6, 7])
def test_tiles_cover_every_pair_exactly_once(n: int, seq_len: int) -> None:
    tiles = windows.tile(n, seq_len)
    pairs = np.concatenate([np.arange(start, stop - 1) for start, stop in tiles])
    np.testing.assert_array_equal(pairs, np.arange(n - 1))  # in order, none twice, none missing
    lengths = tiles[:, 1] - tiles[:, 0]
    assert (lengths[:-1] == seq_len).all() and 2 <= lengths[-1] <= seq_len


def test_tiles_of_eleven_frames_by_four() -> None:
    np.testing.assert_array_equal(windows.tile(11, 4), [[0, 4], [3, 7], [6, 10], [9, 11]])


@pytest.mark.parametrize(("n", "seq_len"), [(1, 3), (5, 1)])
def test_tile_refuses_degenerate_input(n: int, seq_len: int) -> None:
    with pytest.raises(ValueError, match=r"at least 2|seq_len"):
        windows.tile(n, seq_len)


def test_training_starts() -> None:
    np.testing.assert_array_equal(windows.training_starts(10, 4), np.arange(7))
    np.testing.assert_array_equal(windows.training_starts(10, 3, step=2), np.arange(6))  # spans 5 frames
    assert len(windows.training_starts(3, 4)) == 0


def test_same_length_batches_keep_order_and_lengths() -> None:
    lengths = [4, 4, 4, 2, 4, 4, 3]
    batches = windows.SameLengthBatches(SequentialSampler(lengths), 2, lengths=lengths)
    out = list(batches)
    assert out == [[0, 1], [2, 4], [5], [3], [6]] and len(batches) == len(out)
    assert all(len({lengths[i] for i in b}) == 1 for b in out)
    assert sorted(i for b in out for i in b) == list(range(len(lengths)))


def test_validation_loader_sees_every_pair_once(tiny_kitti, tmp_path) -> None:
    """10 frames in windows of 5: tiles (0, 5), (4, 8), (8, 10); the last one is shorter, batched alone."""
    dm = data_module(tiny_kitti, train=["00"], val=["01", "02"], test=["02"], height=32, width=96,
                         seq_len=5, batch_size=2, cache_dir=str(tmp_path), num_workers=0)  # fmt: skip
    dm.prepare_data()
    dm.setup()
    batches = list(dm.val_dataloader())
    ys = [batch["targets"] for batch in batches]
    assert sorted(y.shape[1] for y in ys) == [1, 4, 4]  # 4 full windows in 2 batches, 2 short in 1
    targets = torch.cat([y.reshape(-1, 4, 4) for y in ys]).double().numpy()
    expected = np.concatenate([relative_targets(dm.sequences[n].poses) for n in ("01", "02")])
    assert len(targets) == len(expected) == 18  # every pair of both sequences, none twice
    order = np.lexsort(targets.reshape(len(targets), -1).T)
    np.testing.assert_allclose(
        targets[order], expected[np.lexsort(expected.reshape(len(expected), -1).T)], atol=1e-6
    )
