"""lossvo.data.resident: windows gathered on the training device equal the host loader's, batch for batch."""

from __future__ import annotations

import logging
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from helpers import data_module
from lossvo.console import UserError
from lossvo.data.datamodules import VODataModule
from lossvo.data.transforms import Mirror, Roll

AUGMENTED = [Mirror(0.5), Roll(0.5, 0.01)]


def make_dm(root: Path, cache: Path, **kwargs) -> VODataModule:
    args = {"train": ["00", "01"], "val": ["02"], "test": ["02"], "height": 32, "width": 96, "seq_len": 4,
            "batch_size": 3, "num_workers": 0, "cache_dir": str(cache),
            "windows_per_epoch": 11} | kwargs  # fmt: skip
    dm = data_module(root, **args)
    dm.prepare_data()
    dm.setup("fit")
    return dm


def epoch_batches(dm: VODataModule, split: str, epoch: int, seed: int) -> list[dict[str, torch.Tensor]]:
    """Every batch of one epoch of a split, as the network receives it (on_after_batch_transfer), with the
    global stream seeded first, as a fit is."""
    dm.trainer = SimpleNamespace(training=split == "train")
    torch.manual_seed(seed)  # the run's seed: its initial seed orders the epochs
    loader = dm.train_dataloader() if split == "train" else dm.val_dataloader()
    for sampler in (loader.sampler, getattr(loader.batch_sampler, "sampler", None)):
        if hasattr(sampler, "set_epoch"):
            sampler.set_epoch(epoch)  # as Lightning does before each epoch
    return [dm.on_after_batch_transfer(batch, 0) for batch in loader]


@pytest.mark.parametrize(
    "settings",
    [
        {"frame_steps": [1, 2], "transforms": AUGMENTED},
        {"flow": "dis", "seq_len": 2, "frame_steps": [1, 2], "transforms": AUGMENTED},
    ],
    ids=["frames", "flow"],
)
def test_device_gathering_equals_the_host_loader_batch_for_batch(tiny_kitti: Path, tmp_path: Path,
                                                                 settings: dict) -> None:  # fmt: skip
    """Same seed, same windows in the same order, same augmentation draws (mirror, roll): every entry of
    every batch equal, over two epochs and the validation split."""
    host = make_dm(tiny_kitti, tmp_path, on_device=False, **settings)
    device = make_dm(tiny_kitti, tmp_path, on_device=True, **settings)
    for split, epoch in (("train", 0), ("train", 1), ("val", 0)):
        expected = epoch_batches(host, split, epoch, seed=7)
        got = epoch_batches(device, split, epoch, seed=7)
        assert device.resident_windows(split) is not None and host.resident_windows(split) is None
        assert len(got) == len(expected) >= (4 if split == "train" else 1)  # 11 training windows, 3 a batch
        for a, b in zip(expected, got, strict=True):
            assert a.keys() == b.keys() and ("flow" in a) == ("flow" in settings)
            for key in a:
                assert a[key].dtype == b[key].dtype and torch.equal(a[key], b[key]), (split, epoch, key)


def test_a_budget_the_data_do_not_fit_takes_the_host_loader_and_says_so(
    tiny_kitti: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    dm = make_dm(tiny_kitti, tmp_path, on_device=True, device_budget_gb=1e-6)
    with caplog.at_level(logging.INFO, logger="lossvo"):
        batch = next(iter(dm.train_dataloader()))
        next(iter(dm.val_dataloader()))
    assert "frames" in batch and "frame_index" not in batch
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("data:")]
    assert len(said) == 1 and "host loader (the arrays exceed data.loader.device_budget_gb=1e-06" in said[0]


def test_auto_keeps_the_host_loader_on_a_cpu(tiny_kitti: Path, tmp_path: Path,
                                             caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    dm = make_dm(tiny_kitti, tmp_path)
    with caplog.at_level(logging.INFO, logger="lossvo"):
        assert dm.resident_windows("train") is None
    assert "host loader (data.loader.on_device=auto on a CPU" in caplog.text


def test_on_device_gathers_from_the_resident_arrays(tiny_kitti: Path, tmp_path: Path,
                                                   caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    dm = make_dm(tiny_kitti, tmp_path, on_device=True)
    with caplog.at_level(logging.INFO, logger="lossvo"):
        batch = next(iter(dm.train_dataloader()))
    assert set(batch) == {"split", "frame_index", "target_index", "camera"} and batch["split"] == "train"
    assert batch["frame_index"].shape == (3, 4) and batch["target_index"].shape == (3, 3)
    assert "batches gathered on cpu" in caplog.text
    windows = dm.resident_windows("train")
    assert windows is not None and windows.frames.shape == (20, 3, 32, 96)  # two sequences of 10 frames


@pytest.mark.parametrize("value", ["gpu", 2, None])
def test_bad_on_device(tiny_kitti: Path, tmp_path: Path, value: object) -> None:
    with pytest.raises(UserError, match=r"^data.loader.on_device: expected auto, true or false, got"):
        data_module(tiny_kitti, on_device=value, cache_dir=str(tmp_path))


def test_bad_device_budget(tiny_kitti: Path, tmp_path: Path) -> None:
    with pytest.raises(
        UserError, match=r"^data.loader.device_budget_gb: expected a number of GiB >= 0, got -1"
    ):
        data_module(tiny_kitti, device_budget_gb=-1, cache_dir=str(tmp_path))


@pytest.mark.slow
@pytest.mark.parametrize("network", ["deepvo", "flowvo"])
def test_a_fit_on_the_device_equals_one_on_the_host_loader(
    tiny_kitti: Path, tmp_path: Path, network: str
) -> None:
    """Two epochs with the default augmentations (mirror) through Lightning: every metrics.csv row and every
    result of the evaluation equal."""
    from helpers import fit, scores_of
    from test_flowvo import _flowvo_overrides
    from test_train import compose_train, tiny_overrides

    overrides = (_flowvo_overrides if network == "flowvo" else tiny_overrides)(tiny_kitti, tmp_path / "cache")
    runs = {}
    for on_device in ("false", "true"):
        runs[on_device] = tmp_path / on_device
        mirror = "data.transforms=[{_target_:lossvo.data.transforms.Mirror,p:0.5}]"
        settings = ["trainer.max_epochs=2", mirror, f"data.loader.on_device={on_device}"]
        cfg = compose_train([*overrides, *settings], runs[on_device])
        fit(cfg)
    host, device = ((runs[k] / "metrics.csv").read_text() for k in ("false", "true"))
    assert host == device and len(host.splitlines()) >= 3
    assert scores_of(runs["false"]) == scores_of(runs["true"])
