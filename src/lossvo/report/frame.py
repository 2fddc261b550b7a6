"""The sweep's results as one tidy :class:`pandas.DataFrame`: a row per column (configuration or baseline),
replicate, sequence and metric, beside each job's folder, seed, architecture, data and config choices. The
report's tables are pivots of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from lossvo.evaluation.job_folder import Scores
from lossvo.report.jobs import APE_ROT, APE_TRANS, KITTI_R, KITTI_T, RPE_ROT, RPE_TRANS, Job, metric_value

METRICS = (APE_TRANS, APE_ROT, RPE_TRANS, RPE_ROT, KITTI_T, KITTI_R)
"""The metrics a results frame holds: paths into a sequence's scores (m, rad, %, deg/100 m)."""
CHOICE = "choice."
"""The prefix of a results frame's config-choice columns (``choice.loss``)."""
FIELDS = ("column", "kind", "replicate", "position", "job", "seed", "architecture", "data")
"""The identifying columns of a results frame; ``position`` is the replicate's index in its column."""


@dataclass
class Column:
    """One compared configuration (network) or baseline: ``results[i]`` is ``{sequence: Scores}`` of
    replicate ``replicates[i]`` (a seed; for a network, of job ``jobs[i]``); ``kind`` is
    :data:`lossvo.report.tables.NETWORK` or ``BASELINE``."""

    label: str
    kind: str
    replicates: list[str]
    results: list[dict[str, Scores]]
    jobs: list[Job] = field(default_factory=list)
    architecture: str | None = None


def metric_name(path: Sequence[str]) -> str:
    """A metric's name in a results frame: its path joined by dots (``ape.trans.rmse``)."""
    return ".".join(path)


def column_rows(column: Column) -> list[dict[str, Any]]:
    """The rows of one column: per replicate, sequence and metric its value, job and config choices."""
    rows = []
    for position, (replicate, per_sequence) in enumerate(zip(column.replicates, column.results, strict=True)):
        job = column.jobs[position] if position < len(column.jobs) else None
        name, seed, data = (job.path.name, job.seed, job.data) if job else (None, None, None)
        values = (column.label, column.kind, replicate, position, name, seed, column.architecture, data)
        head: dict[str, Any] = dict(zip(FIELDS, values, strict=True))
        head.update({f"{CHOICE}{k}": v for k, v in (job.choices if job else {}).items()})
        for sequence, scores in per_sequence.items():
            for path in METRICS:
                value = metric_value(scores, path)
                rows.append(head | {"sequence": sequence, "metric": metric_name(path), "value": value})
    return rows


def results_frame(columns: Sequence[Column]) -> pd.DataFrame:
    """Every column's results as one tidy table (``value`` float64, NaN where missing)."""
    rows = [row for column in columns for row in column_rows(column)]
    frame = pd.DataFrame(rows, columns=[*FIELDS, "sequence", "metric", "value"] if not rows else None)
    frame["value"] = frame["value"].astype(np.float64)
    return frame


def metric_matrix(
    frame: pd.DataFrame, column: Column, path: Sequence[str], sequences: Sequence[str]
) -> np.ndarray:
    """(replicates, sequences) float64 values of one metric of ``column`` in ``frame``, replicates in the
    column's order; NaN where missing."""
    rows = frame[(frame["column"] == column.label) & (frame["metric"] == metric_name(path))]
    table = rows.pivot(index="position", columns="sequence", values="value")
    table = table.reindex(index=range(len(column.results)), columns=list(sequences))
    return table.to_numpy(dtype=np.float64)
