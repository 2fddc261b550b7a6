"""``metrics.csv``: the run's per-epoch record, only ever appended to.

Lightning's CSV logger deletes a ``metrics.csv`` it finds in its folder; :class:`CSVLogger` keeps it and
appends, so a resumed run (or one stopped after its last epoch and run again) keeps every row already
written. The ``epoch`` column is Lightning's, counted from 0; ``step`` is the global step.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

from lightning.pytorch.loggers import CSVLogger as LightningCSVLogger
from lightning.pytorch.loggers.csv_logs import ExperimentWriter
from lightning.pytorch.loggers.logger import rank_zero_experiment

from lossvo.atomic import atomic_path

NAME = "metrics.csv"


def read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    """The header and the rows of a ``metrics.csv`` (empty for a missing file)."""
    if not path.is_file():
        return [], []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
        return list(reader.fieldnames or []), rows


def write_rows(path: Path, header: list[str], rows: list[dict[str, str]]) -> None:
    """Write a ``metrics.csv`` whole, atomically."""
    with atomic_path(path, suffix=".csv") as tmp, tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=header)
        writer.writeheader()
        writer.writerows(rows)


class AppendingWriter(ExperimentWriter):
    """Lightning's experiment writer, keeping the ``metrics.csv`` it finds: new rows are appended, and a
    new column rewrites the file atomically with every row it held."""

    def _check_log_dir_exists(self) -> None:  # Lightning's deletes metrics.csv here
        self.metrics_keys, _ = read_rows(Path(self.metrics_file_path))

    def _rewrite_with_new_header(self, fieldnames: list[str]) -> None:
        _, rows = read_rows(Path(self.metrics_file_path))
        write_rows(Path(self.metrics_file_path), fieldnames, rows)


class CSVLogger(LightningCSVLogger):
    """Lightning's CSV logger writing through :class:`AppendingWriter` (``hparams.yaml`` as Lightning's)."""

    @property
    @rank_zero_experiment
    def experiment(self) -> AppendingWriter:
        if not isinstance(self._experiment, AppendingWriter):
            self._fs.makedirs(self.root_dir, exist_ok=True)
            self._experiment = AppendingWriter(log_dir=self.log_dir)
        return self._experiment


def _before(row: dict[str, str], last_epoch: int, global_step: int) -> bool:
    """Whether a row was logged before a checkpoint of ``last_epoch`` (0-based) at ``global_step``: rows
    of later epochs, and rows without an epoch (the learning rate) at or after that step, come again."""
    if row.get("epoch"):
        return int(float(row["epoch"])) <= last_epoch
    return bool(row.get("step")) and int(float(row["step"])) < global_step


def continue_history(path: Path, source: Path, last_epoch: int, global_step: int) -> None:
    """Prepare ``path`` for a run that continues a checkpoint of ``last_epoch`` (-1: none) at ``global_step``.

    ``source`` is the ``metrics.csv`` of the checkpoint's job folder. In the same folder, rows of an epoch
    that never reached a checkpoint (a stop between the logger's write and the checkpoint's) are
    replaced, as that epoch runs again; every other row stays. In a new folder, the source's rows up to
    the checkpoint are written first, so that the file holds every epoch once.
    """
    header, rows = read_rows(source)
    kept = [row for row in rows if _before(row, last_epoch, global_step)]
    same = path.exists() and source.exists() and os.path.samefile(path, source)
    if header and (len(kept) < len(rows) if same else not path.exists()):
        write_rows(path, header, kept)


def final_metrics(path: Path) -> dict[str, float]:
    """The last value of every metric column of a ``metrics.csv`` (``epoch`` and ``step`` aside)."""
    header, rows = read_rows(path)
    last: dict[str, float] = {}
    for row in rows:
        last.update({key: float(value) for key, value in row.items() if value not in ("", None)})
    return {key: last[key] for key in header if key in last and key not in ("epoch", "step")}
