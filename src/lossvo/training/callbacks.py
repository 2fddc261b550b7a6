"""Lightning callbacks that no library provides in this form: a line per epoch, a progress bar on a terminal
only, and trajectory errors of the whole validation sequences during fit.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback, RichProgressBar

from lossvo.checks import is_integer
from lossvo.console import UserError
from lossvo.data.datamodules import VODataModule
from lossvo.evaluation.results import PooledScores, predict_and_score

log = logging.getLogger("lossvo")

SUMMARY_KEYS = ("train/loss", "val/loss", "val/score", "val/trans_err_m", "val/rot_err_rad")


class EpochSummary(Callback):
    """Logs one line per epoch: epoch, seconds, and the losses and yardsticks (``SUMMARY_KEYS``)."""

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._start = time.perf_counter()

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        metrics = trainer.callback_metrics
        values = " ".join(f"{k}={metrics[k].item():.4g}" for k in SUMMARY_KEYS if k in metrics)
        elapsed = time.perf_counter() - getattr(self, "_start", time.perf_counter())
        log.info("epoch %d/%d (%.1f s) %s", trainer.current_epoch + 1, trainer.max_epochs, elapsed, values)


class EpochProgressBar(RichProgressBar):
    """Lightning's Rich bar with epochs counted from 1, ``val/loss`` and ``val/score`` beside the loss."""

    SHOWN = ("val/loss", "val/score")

    def _get_train_description(self, current_epoch: int) -> str:
        total = self.trainer.max_epochs
        return f"Epoch {current_epoch + 1}" + (f"/{total}" if total is not None and total > 0 else "")

    def get_metrics(self, trainer: L.Trainer, pl_module: L.LightningModule) -> dict[str, Any]:
        shown = {
            k: f"{trainer.callback_metrics[k].item():.4g}"
            for k in self.SHOWN
            if k in trainer.callback_metrics
        }
        return {**super().get_metrics(trainer, pl_module), **shown}


def progress() -> Callback | None:
    """An :class:`EpochProgressBar` when stdout is a terminal, else None (no bar)."""
    return EpochProgressBar() if sys.stdout.isatty() else None


class TrajectoryValidation(Callback):
    """Every ``every_n_epochs`` epochs, integrate the validation sequences and log their pooled trajectory
    errors (APE unaligned, RPE over one frame, KITTI's where a 100 m segment exists: docs/training.md).
    A datamodule other than lossvo's (a benchmark's) is skipped."""

    def __init__(self, every_n_epochs: int = 1, mirror_average: bool = False) -> None:
        if not is_integer(every_n_epochs, 1):
            raise UserError(f"every_n_epochs: expected an integer >= 1, got {every_n_epochs!r}")
        if not isinstance(mirror_average, bool):
            raise UserError(f"mirror_average: expected true or false, got {mirror_average!r}")
        self.every_n_epochs, self.mirror_average = every_n_epochs, mirror_average

    @staticmethod
    def _share(
        names: list[str], trainer: L.Trainer, pl_module: L.LightningModule
    ) -> tuple[list[str], torch.device]:
        """This process's validation sequences and its metric states' device (DDP: every world_size-th)."""
        world, rank = trainer.world_size, trainer.global_rank
        if world > 1 and len(names) >= world:
            return names[rank::world], pl_module.device
        return names, torch.device("cpu")

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or (trainer.current_epoch + 1) % self.every_n_epochs:
            return
        datamodule = trainer.datamodule  # type: ignore[attr-defined]  # set by Lightning, undeclared
        if not isinstance(datamodule, VODataModule) or not datamodule.splits.get("val"):
            return
        pooled = PooledScores()  # no alignment, RPE over 1 frame
        names, device = self._share(list(datamodule.splits["val"]), trainer, pl_module)
        for name in names:
            gt = datamodule.sequence_poses(name)
            if gt is not None:
                predict_and_score(
                    pl_module, datamodule, name, gt, pooled, device=device, mirror_average=self.mirror_average
                )
        computed = pooled.compute()
        if computed is None:
            return
        values = {
            "val/ape_trans_rmse": computed["ape"]["trans"]["rmse"],
            "val/rpe_trans_rmse": computed["rpe"]["trans"]["rmse"],
            "val/rpe_rot_rmse": computed["rpe"]["rot_rad"]["rmse"],
        }
        t_err, r_err = computed["kitti"]["t_err_pct"], computed["kitti"]["r_err_deg_per_100m"]
        if t_err is not None and r_err is not None:  # both or neither: no segment
            values["val/kitti_t_err"] = t_err
            values["val/kitti_r_err"] = r_err
        for key, value in values.items():
            pl_module.log(key, torch.tensor(value, dtype=torch.float32), on_step=False, on_epoch=True)
