"""Lightning callbacks that no library provides in this form.

- :func:`progress` picks Lightning's Rich progress bar on a terminal and, when output goes to a file or
  a cluster log (no TTY), one plain summary line per epoch instead of thousands of redrawn bars.
"""

from __future__ import annotations

import logging
import sys
import time

import lightning as L
from lightning.pytorch.callbacks import Callback, RichProgressBar

log = logging.getLogger("lossvo")

SUMMARY_KEYS = ("train/loss", "val/loss", "val/trans_err_m", "val/rot_err_rad")


class EpochSummary(Callback):
    """Logs one line per epoch: epoch, seconds, and the losses and yardsticks (``SUMMARY_KEYS``)."""

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._start = time.perf_counter()

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        metrics = trainer.callback_metrics
        values = " ".join(f"{k}={metrics[k].item():.4g}" for k in SUMMARY_KEYS if k in metrics)
        elapsed = time.perf_counter() - getattr(self, "_start", time.perf_counter())
        log.info("epoch %d/%d (%.1f s) %s", trainer.current_epoch + 1, trainer.max_epochs, elapsed, values)


def progress(rich_on_tty: bool = True) -> Callback:
    """A Rich progress bar when stdout is a terminal, else :class:`EpochSummary` lines."""
    if rich_on_tty and sys.stdout.isatty():
        return RichProgressBar()
    return EpochSummary()
