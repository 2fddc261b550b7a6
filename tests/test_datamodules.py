"""lossvo.data.datamodules and frame_cache: windows, targets, cache reuse and repair, statistics."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from helpers import data_module
from lossvo.console import UserError
from lossvo.data import frame_cache, kitti
from lossvo.data.datamodules import VODataModule
from lossvo.data.transforms import Mirror, Roll, spec


def make_dm(root: Path, cache: Path, **kwargs) -> VODataModule:
    args = {"train": ["00", "01"], "val": ["02"], "test": ["00", "01", "02"], "height": 32, "width": 96,
            "seq_len": 4, "batch_size": 3, "num_workers": 0, "cache_dir": str(cache)} | kwargs  # fmt: skip
    dm = data_module(root, **args)
    dm.prepare_data()
    dm.setup("fit")
    return dm


def test_windows_and_targets(tiny_kitti: Path, tmp_path: Path) -> None:
    dm = make_dm(tiny_kitti, tmp_path)
    batch = next(iter(dm.train_dataloader()))
    assert batch["frames"].shape == (3, 4, 3, 32, 96) and batch["frames"].dtype == torch.uint8  # as loaded
    prepared = dm.on_after_batch_transfer(batch, 0)  # as the model receives it
    frames, targets = prepared["frames"], prepared["targets"]
    assert prepared["K"].shape == (3, 3, 3) and "flow" not in prepared
    assert frames.shape == (3, 4, 3, 32, 96) and frames.dtype == torch.float32
    assert targets.shape == (3, 3, 4, 4) and targets.dtype == torch.float32
    # a window at every frame: 10 - 4 + 1 per training sequence
    assert len(dm.datasets["train"]) == 2 * 7
    y = dm.datasets["train"][8]["targets"]  # sequence 01, window starting at frame 1
    poses = kitti.read_poses(tiny_kitti / "poses" / "01.txt")
    expected = np.linalg.inv(poses[1:4]) @ poses[2:5]
    np.testing.assert_allclose(y.numpy(), expected, atol=1e-6)


def test_frames_are_area_resized_rgb_in_h_w_order(tiny_kitti: Path, tmp_path: Path) -> None:
    dm = make_dm(tiny_kitti, tmp_path)
    cached = dm.sequence_frames("02")
    assert cached.shape == (10, 3, 32, 96) and cached.dtype == np.uint8
    bgr = cv2.imread(str(tiny_kitti / "sequences" / "02" / "image_2" / "000003.png"))
    expected = cv2.cvtColor(cv2.resize(bgr, (96, 32), interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(cached[3], expected.transpose(2, 0, 1))
    x = dm.datasets["val"][0]["frames"]
    assert x.shape == (4, 3, 32, 96)
    np.testing.assert_array_equal(x.numpy(), cached[0:4])


def test_validation_sees_every_pair_exactly_once(tiny_kitti: Path, tmp_path: Path) -> None:
    dm = make_dm(tiny_kitti, tmp_path)
    ds = dm.datasets["val"]  # 10 frames, windows of 4 frames: starts 0, 3, 6 cover pairs 0..8
    starts = ds.index[:, 1].tolist()
    pairs = [p for s in starts for p in range(s, s + 3)]
    assert sorted(pairs) == list(range(9))
    ys = torch.cat([ds[i]["targets"] for i in range(len(ds))])
    targets = kitti.relative_targets(kitti.read_poses(tiny_kitti / "poses" / "02.txt"))
    np.testing.assert_allclose(ys.numpy(), targets, atol=1e-6)


def test_statistics_come_from_the_training_split(tiny_kitti: Path, tmp_path: Path) -> None:
    dm = make_dm(tiny_kitti, tmp_path)
    train = np.concatenate([dm.sequence_frames(n) for n in ("00", "01")]).astype(np.float64) / 255
    np.testing.assert_allclose(dm.mean, train.mean(axis=(0, 2, 3)), rtol=1e-9)
    np.testing.assert_allclose(dm.std, train.std(axis=(0, 2, 3)), rtol=1e-6)
    other = make_dm(tiny_kitti, tmp_path, train=["02"], val=["00"])
    assert not np.allclose(other.mean, dm.mean)
    flownet = make_dm(tiny_kitti, tmp_path, normalization="flownet")
    x = flownet.datasets["train"][0]["frames"]
    torch.testing.assert_close(flownet.normalize(x), x.float() / 255.0 - 0.5)
    normalized = dm.normalize(
        torch.cat([dm.datasets["train"][i]["frames"] for i in (0, 7)])
    )  # both sequences
    assert normalized.mean().abs() < 0.5 and normalized.dtype == torch.float32


def test_cache_is_reused_without_decoding(tiny_kitti: Path, tmp_path: Path, monkeypatch) -> None:
    make_dm(tiny_kitti, tmp_path)

    def no_decoding(*args, **kwargs):
        raise AssertionError("a PNG was decoded although the cache is complete")

    monkeypatch.setattr(cv2, "imread", no_decoding)
    dm = make_dm(tiny_kitti, tmp_path)
    assert len(dm.datasets["train"]) > 0


@pytest.mark.parametrize("damage", ["truncate", "drop_manifest", "garbage"])
def test_corrupt_cache_is_rebuilt(tiny_kitti: Path, tmp_path: Path, damage: str) -> None:
    dm = make_dm(tiny_kitti, tmp_path)
    good = np.array(dm.sequence_frames("01"))
    data, manifest = frame_cache.files(dm.cache_path(), "01")
    if damage == "truncate":  # an interrupted write
        data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    elif damage == "drop_manifest":
        manifest.unlink()
    else:
        data.write_bytes(b"not a numpy file")
    rebuilt = make_dm(tiny_kitti, tmp_path)
    np.testing.assert_array_equal(rebuilt.sequence_frames("01"), good)
    assert json.loads(manifest.read_text())["shape"] == [10, 3, 32, 96]


def test_changed_dataset_invalidates_the_cache(kitti_copy: Path, tmp_path: Path) -> None:
    dm = make_dm(kitti_copy, tmp_path)
    before = np.array(dm.sequence_frames("00")[5])
    src = kitti_copy / "sequences" / "00" / "image_2"
    (src / "000005.png").write_bytes((src / "000006.png").read_bytes())
    after = make_dm(kitti_copy, tmp_path).sequence_frames("00")[5]
    assert not np.array_equal(before, after)


def test_workers_load_the_same_windows(tiny_kitti: Path, tmp_path: Path) -> None:
    dm = make_dm(tiny_kitti, tmp_path)
    worker_dm = make_dm(tiny_kitti, tmp_path, num_workers=1)
    a = torch.cat([batch["frames"] for batch in dm.val_dataloader()])
    b = torch.cat([batch["frames"] for batch in worker_dm.val_dataloader()])
    torch.testing.assert_close(a, b)


def test_the_description_records_the_transforms_and_rebuilds_the_datamodule(
    tiny_kitti: Path, tmp_path: Path
) -> None:
    dm = make_dm(tiny_kitti, tmp_path, transforms=[Mirror(0.5), Roll(0.5, 0.01)])
    described = dm.description()
    assert described["transforms"] == [spec(Mirror(0.5)), spec(Roll(0.5, 0.01))]
    torch.save(described, tmp_path / "described.pt")
    torch.load(tmp_path / "described.pt", weights_only=True)  # primitives only, as a checkpoint holds them
    arguments = {k: v for k, v in described.items() if k not in ("dataset_root", "intrinsics", "statistics")}
    rebuilt = instantiate(arguments, _convert_="all")
    assert rebuilt.transforms == dm.transforms


def test_windows_per_epoch_draws_a_fresh_subset(tiny_kitti: Path, tmp_path: Path) -> None:
    dm = make_dm(tiny_kitti, tmp_path, windows_per_epoch=6, batch_size=2)
    loader = dm.train_dataloader()
    epochs = []
    for epoch in (0, 1, 0):  # Lightning sets the sampler's epoch before each training epoch
        loader.sampler.set_epoch(epoch)
        epochs.append(torch.cat([batch["targets"] for batch in loader]))
    assert [len(e) for e in epochs] == [6, 6, 6]
    assert not torch.equal(epochs[0], epochs[1])
    assert torch.equal(epochs[0], epochs[2])  # the order depends on the seed and the epoch only
    assert len(make_dm(tiny_kitti, tmp_path, windows_per_epoch=1000).train_dataloader().sampler) == 14


def test_transforms_only_when_asked_and_only_in_training(tiny_kitti: Path, tmp_path: Path) -> None:
    batch = next(iter(make_dm(tiny_kitti, tmp_path).val_dataloader()))
    dm = make_dm(tiny_kitti, tmp_path, transforms=[Mirror(1.0)])
    dm.trainer = SimpleNamespace(training=True)
    frames = dm.on_after_batch_transfer(batch, 0)["frames"]
    torch.testing.assert_close(frames, dm.normalize(batch["frames"].flip(-1)))
    dm.trainer = SimpleNamespace(training=False)
    assert torch.equal(dm.on_after_batch_transfer(batch, 0)["frames"], dm.normalize(batch["frames"]))
    plain = make_dm(tiny_kitti, tmp_path)
    plain.trainer = SimpleNamespace(training=True)
    assert torch.equal(plain.on_after_batch_transfer(batch, 0)["frames"], plain.normalize(batch["frames"]))


# -- bad input --------------------------------------------------------------------------------------


def test_differing_image_sizes(kitti_copy: Path, tmp_path: Path) -> None:
    path = kitti_copy / "sequences" / "01" / "image_2" / "000007.png"
    cv2.imwrite(str(path), np.zeros((40, 100, 3), np.uint8))
    with pytest.raises(
        kitti.KittiFormatError, match=r"000007\.png: image is 100x40 \(WxH\) but the sequence's first"
    ):
        make_dm(kitti_copy, tmp_path)


def test_truncated_png_fails_before_training(kitti_copy: Path, tmp_path: Path) -> None:
    path = kitti_copy / "sequences" / "02" / "image_2" / "000002.png"
    path.write_bytes(path.read_bytes()[:-20])
    with pytest.raises(kitti.KittiFormatError, match=r"000002\.png: not a complete PNG file"):
        make_dm(kitti_copy, tmp_path)


def test_undecodable_png_fails_before_training(kitti_copy: Path, tmp_path: Path) -> None:
    path = kitti_copy / "sequences" / "00" / "image_2" / "000001.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 50 + b"\x00\x00\x00\x00IEND\xaeB`\x82")
    with pytest.raises(kitti.KittiFormatError, match=r"000001\.png: unreadable image"):
        make_dm(kitti_copy, tmp_path)


def test_test_sequences_may_lack_poses(kitti_copy: Path, tmp_path: Path) -> None:
    (kitti_copy / "poses" / "02.txt").unlink()
    dm = make_dm(kitti_copy, tmp_path, val=["01"], test=["01", "02"])
    assert dm.sequence_poses("02") is None and dm.sequence_frames("02").shape[0] == 10
    assert len(dm.datasets["test"]) == 3  # the windows of 01 only
    with pytest.raises(kitti.KittiFormatError, match=r"02\.txt: no pose file for sequence 02"):
        make_dm(kitti_copy, tmp_path, val=["02"], test=["02"])


def test_missing_sequence_is_named(tiny_kitti: Path, tmp_path: Path) -> None:
    with pytest.raises(
        UserError, match=r"data\.splits\.val: no sequence '05' in .* \(kitti layout; it has 00, 01, 02\)"
    ):
        make_dm(tiny_kitti, tmp_path, val=["05"])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"seq_len": 1}, r"data\.windows\.seq_len: expected an integer >= 2"),
        ({"height": 8}, r"data\.frames\.height: expected an integer >= 16"),
        ({"batch_size": 0}, r"data\.windows\.batch_size: expected an integer >= 1"),
        ({"normalization": "imagenet"}, r"data\.frames\.normalization: expected one of"),
        ({"train": []}, r"data\.splits\.train: expected at least one"),
        ({"transforms": [{"p": 0.5}]}, r"data\.transforms: expected a list of batch transforms"),
        ({"windows_per_epoch": 0}, r"data\.windows\.per_epoch: expected null or an integer >= 1"),
    ],
)
def test_bad_settings(tiny_kitti: Path, tmp_path: Path, kwargs: dict, message: str) -> None:
    with pytest.raises(UserError, match=message):
        make_dm(tiny_kitti, tmp_path, **kwargs)


def test_window_longer_than_sequences(tiny_kitti: Path, tmp_path: Path) -> None:
    with pytest.raises(
        UserError, match=r"data\.windows\.seq_len: 11 frames is longer than every training sequence"
    ):
        make_dm(tiny_kitti, tmp_path, seq_len=11)


def test_sequence_names_from_hydra_integers(tiny_kitti: Path, tmp_path: Path) -> None:
    dm = make_dm(
        tiny_kitti, tmp_path, train=[0, 1], val=2, test=[2]
    )  # data.splits.val=02 arrives as the int 2
    assert dm.splits == {"train": ("00", "01"), "val": ("02",), "test": ("02",), "unseen": ()}


@pytest.mark.slow
def test_synthetic_datamodule_renders_on_first_use(tmp_path: Path) -> None:
    dm = data_module(tmp_path / "synth", "synthetic", frames=6, render_height=48, render_width=160,
                             train=["00"], val=["01"], test=["01"], height=32, width=96, seq_len=3,
                             num_workers=0, cache_dir=str(tmp_path / "cache"))  # fmt: skip
    dm.prepare_data()
    dm.setup("fit")
    assert (tmp_path / "synth" / "poses" / "00.txt").is_file()
    batch = next(iter(dm.train_dataloader()))
    assert batch["frames"].shape[1:] == (3, 3, 32, 96) and batch["targets"].shape[1:] == (2, 4, 4)


@pytest.mark.parametrize("split", ["train", "val", "test", "unseen"])
def test_unknown_synthetic_sequence_is_named_before_rendering(tmp_path: Path, split: str) -> None:
    frames = {"00": 6, "01": 6}
    splits = {"train": ["00"], "val": ["01"], "test": ["01"], "unseen": []} | {split: ["99"]}
    message = rf"^data\.splits\.{split}: sequence '99' not found \(available: 00, 01\)$"
    with pytest.raises(UserError, match=message):
        data_module(tmp_path / "synth", "synthetic", frames=frames, cache_dir=str(tmp_path), **splits)
    assert not (tmp_path / "synth").exists()


def test_frame_steps_add_windows_of_every_other_frame_with_recomputed_targets(
    tiny_kitti: Path, tmp_path: Path
) -> None:
    dm = data_module(tiny_kitti, train=["00"], val=["02"], test=["02"], height=32, width=96,
                         seq_len=3, cache_dir=str(tmp_path), frame_steps=[1, 2])  # fmt: skip
    dm.prepare_data()
    dm.setup()
    poses = kitti.read_poses(tiny_kitti / "poses" / "00.txt")
    train = dm.datasets["train"]
    n = len(poses)
    assert len(train) == (n - 2) + (n - 4)  # windows of 3 frames at step 1, then at step 2
    frames, targets = train[n - 2]["frames"], train[n - 2]["targets"]  # the first step-2 window: 0, 2, 4
    cached = dm.sequence_frames("00")
    np.testing.assert_array_equal(frames.numpy(), cached[[0, 2, 4]])
    expected = [np.linalg.inv(poses[k]) @ poses[k + 2] for k in (0, 2)]
    np.testing.assert_allclose(targets.numpy(), np.array(expected), atol=1e-5)
    assert all(int(step) == 1 for step in dm.datasets["val"].index[:, 3])  # validation: consecutive only


@pytest.mark.parametrize(
    ("steps", "expected"),
    [([], "a list of integers >= 1"), ([0, 1], "a list of integers >= 1"), ("2", "a list"),
     ([1.5], "an int, got 1.5")],
)  # fmt: skip
def test_bad_frame_steps(tiny_kitti: Path, tmp_path: Path, steps, expected: str) -> None:
    with pytest.raises(UserError, match=rf"^data\.windows\.frame_steps(\[0\])?: expected {expected}"):
        data_module(tiny_kitti, cache_dir=str(tmp_path), frame_steps=steps)
