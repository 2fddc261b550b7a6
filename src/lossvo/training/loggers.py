"""Lightning's experiment loggers as a run uses them: the CSV logger appending to the ``metrics.csv`` it
finds (instead of deleting it), the file's rows when a run continues a checkpoint, and W&B's logger.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from lightning.pytorch import loggers
from lightning.pytorch.loggers.csv_logs import ExperimentWriter
from lightning.pytorch.loggers.logger import rank_zero_experiment

from lossvo.evaluation import job_folder
from lossvo.evaluation.job_folder import MetricsTable


class AppendingWriter(ExperimentWriter):
    """Lightning's experiment writer appending to the ``metrics.csv`` it finds (a new column rewrites it)."""

    def _check_log_dir_exists(self) -> None:  # Lightning's deletes metrics.csv here
        self.metrics_keys = list(job_folder.read_metrics(Path(self.log_dir)).header)

    def save(self) -> None:
        if self.metrics:
            self._record_new_keys()
            job_folder.append_metrics(Path(self.log_dir), self.metrics_keys, self.metrics)
            self.metrics = []


class CSVLogger(loggers.CSVLogger):
    """Lightning's CSV logger writing through :class:`AppendingWriter` (``hparams.yaml`` as Lightning's)."""

    @property
    @rank_zero_experiment
    def experiment(self) -> AppendingWriter:
        if not isinstance(self._experiment, AppendingWriter):
            self._fs.makedirs(self.root_dir, exist_ok=True)
            self._experiment = AppendingWriter(log_dir=self.log_dir)
        return self._experiment


class WandbLogger(loggers.WandbLogger):
    """Lightning's W&B logger without the ``anonymous`` argument (W&B warns about it on every run)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._wandb_init.pop("anonymous", None)


def _before(row: dict[str, str], last_epoch: int, global_step: int) -> bool:
    """Whether a row was logged before a checkpoint of ``last_epoch`` (0-based) at ``global_step``."""
    if row.get("epoch"):
        return int(float(row["epoch"])) <= last_epoch
    return bool(row.get("step")) and int(float(row["step"])) < global_step


def continue_history(folder: Path, source: Path, last_epoch: int, global_step: int) -> None:
    """Prepare ``folder``'s ``metrics.csv`` for a run continuing a checkpoint of ``last_epoch`` (-1: none) in
    ``source``: rows after the checkpoint (or cut short) go, as their epoch runs again; a new folder starts
    with the source's rows up to the checkpoint, so the file holds every epoch once."""
    table = job_folder.read_metrics(source)
    kept = tuple(row for row in table.rows if _before(row, last_epoch, global_step))
    path = folder / job_folder.METRICS
    same = path.exists() and (source / job_folder.METRICS).exists() and os.path.samefile(folder, source)
    changed = len(kept) < len(table.rows) or table.damage is not None
    if table.header and (changed if same else not path.exists()):
        job_folder.write_metrics(folder, MetricsTable(table.header, kept))
