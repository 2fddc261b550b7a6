"""Training: fast_dev_run per loss (in process), checkpoints reload, bad configs fail at start."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, open_dict

from helpers import fit
from lossvo.console import UserError
from lossvo.train import CONFIG_DIR
from lossvo.training import fitting
from lossvo.training.module import NonFiniteLossError, VOModule


def tiny_overrides(root: Path, cache: Path) -> list[str]:
    """The tiny synthetic dataset through the real KITTI reader, a very small DeepVO, CSV logging."""
    return [
        "data=kitti",
        f"data.sources.kitti.root={root}",
        f"data.frames.cache_dir={cache}",
        "data.splits.train=[00,01]",
        "data.splits.val=[02]",
        "data.splits.test=[02]",
        "data.frames.height=64",
        "data.frames.width=96",
        "data.windows.seq_len=3",
        "data.windows.batch_size=4",
        "data.loader.num_workers=0",
        "model.width_mult=0.0625",
        "model.hidden_size=16",
        "trainer.log_every_n_steps=1",
    ]


def compose_train(overrides: list[str], out: Path) -> DictConfig:
    """Compose conf/train.yaml as `python -m lossvo.train` would, with its output folder set to ``out``."""
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(out)
        cfg.hydra.job.num = 0
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        del cfg.hydra
    return cfg


@pytest.mark.slow
@pytest.mark.parametrize("loss", ["euler", "quat", "chordal", "geodesic", "sixd", "svd", "quat10d"])
def test_fast_dev_run_for_every_loss(tiny_kitti: Path, tmp_path: Path, loss: str) -> None:
    overrides = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), f"loss={loss}", "+trainer.fast_dev_run=1"]
    cfg = compose_train(overrides, tmp_path / "run")
    metrics = fit(cfg)
    assert {"train/loss", "val/loss", "val/score", "val/rot_err_rad", "val/trans_err_m"} <= set(metrics)
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())


@pytest.mark.slow
def test_checkpoint_reloads_with_weights_only(tiny_kitti: Path, tmp_path: Path) -> None:
    overrides = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), "loss=quat", "trainer.max_epochs=1"]
    cfg = compose_train(overrides, tmp_path / "run")
    (tmp_path / "run" / ".hydra").mkdir(parents=True)  # as Hydra leaves a job folder before training
    (tmp_path / "run" / "train.log").write_text("")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit(cfg)
    assert not [w for w in caught if "will be deleted" in str(w.message)]  # nothing to delete: no warning
    ckpt = tmp_path / "run" / "checkpoints" / "best.ckpt"
    assert ckpt.is_file() and (tmp_path / "run" / "checkpoints" / "last.ckpt").is_file()
    torch.load(ckpt, map_location="cpu")  # torch's default: weights_only=True
    module = VOModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    assert module.loss.dim == 7 and module.loss.k == 400.0  # matched: 100 / (1/4)
    frames = torch.rand(2, 3, 3, 64, 96)
    module.eval()
    assert module({"frames": frames}).shape == (2, 2, 7)
    metrics_csv = tmp_path / "run" / "metrics.csv"
    assert "val/rot_err_rad" in metrics_csv.read_text().splitlines()[0]


@pytest.mark.slow
def test_head_size_follows_the_loss(tiny_kitti: Path, tmp_path: Path) -> None:
    for loss, dim in (("euler", 6), ("quat", 7), ("sixd", 9), ("svd", 12), ("quat10d", 13)):
        cfg = compose_train([*tiny_overrides(tiny_kitti, tmp_path), f"loss={loss}"], tmp_path / "run")
        assert cfg.model.out_dim == dim


def test_non_finite_loss_names_step_batch_and_term(tiny_kitti: Path, tmp_path: Path) -> None:
    overrides = [*tiny_overrides(tiny_kitti, tmp_path / "cache"), "loss=euler", "optimizer.lr=1e30",
                 "trainer.max_epochs=3", "callbacks.model_checkpoint=null"]  # fmt: skip
    cfg = compose_train(overrides, tmp_path / "run")
    expected = r"non-finite loss at epoch \d+, global step \d+, batch \d+: trans_loss, rot_loss = nan"
    with pytest.raises(NonFiniteLossError, match=expected):
        fit(cfg)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("loss=eular", "Could not find 'loss/eular'"),
        ("model=deepvo_tiny", "Could not find 'model/deepvo_tiny'"),
        ("loss.kk=3", "Could not override 'loss.kk'"),
        ("data.hieght=3", "Could not override 'data.hieght'"),
    ],
)
def test_bad_names_fail_with_hydra_message(tmp_path: Path, override: str, message: str) -> None:
    with pytest.raises(Exception, match=message):
        compose_train([override], tmp_path)


def test_callback_without_target_fails_before_training(tiny_kitti: Path, tmp_path: Path) -> None:
    cfg = compose_train([*tiny_overrides(tiny_kitti, tmp_path), "+callbacks.oops.x=1"], tmp_path / "run")
    with pytest.raises(UserError, match=r"callbacks\.oops: expected a config with a _target_"):
        fitting.build(cfg)


@pytest.mark.parametrize("override", ["scheduler=none", "~scheduler"])
def test_no_scheduler(tiny_kitti: Path, tmp_path: Path, override: str) -> None:
    cfg = compose_train([*tiny_overrides(tiny_kitti, tmp_path / "cache"), override], tmp_path / "run")
    _, module, _ = fitting.build(cfg)
    assert module.hparams["scheduler"] is None
