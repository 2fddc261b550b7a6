"""The per-sequence metric tables of a sweep report (:data:`TABLES`: mean ± sample std over seeds, a mean
row, the row's minimum bold) and their markdown, CSV and LaTeX (:mod:`lossvo.table_render`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from lossvo import table_render
from lossvo.report.frame import Column, metric_matrix, results_frame
from lossvo.report.jobs import APE_ROT, APE_TRANS, KITTI_R, KITTI_T, RPE_ROT, RPE_TRANS
from lossvo.table_render import Rows

NETWORK, BASELINE = "network", "baseline"
MEAN_ROW = "mean"
UNKNOWN_ARCHITECTURE = "?"


def with_architecture(header: Sequence[str], rows: Sequence[Sequence[object]], by_architecture: bool) -> Rows:
    """A table of ``rows``, each led by its architecture (None: unknown): an ``architecture`` column first
    where ``by_architecture``, else without it."""
    if by_architecture:
        return Rows(["architecture", *header], [[a or UNKNOWN_ARCHITECTURE, *row] for a, *row in rows])
    return Rows(header, [row[1:] for row in rows])


@dataclass(frozen=True)
class TableSpec:
    """What a table holds: ``metrics`` are (header, path into a sequence's results entry)."""

    key: str
    title: str
    metrics: tuple[tuple[str, tuple[str, ...]], ...]


TABLES = (
    TableSpec(
        "translation", "Table I: translation RMSE (m)", (("APE [m]", APE_TRANS), ("RPE [m]", RPE_TRANS))
    ),
    TableSpec("rotation", "Table II: rotation RMSE (rad)", (("APE [rad]", APE_ROT), ("RPE [rad]", RPE_ROT))),
    TableSpec(
        "kitti",
        "Table III: KITTI odometry error (mean over 100-800 m segments)",
        (("t_err [%]", KITTI_T), ("r_err [deg/100m]", KITTI_R)),
    ),
)


def samples(column: Column, path: Sequence[str], sequences: Sequence[str]) -> np.ndarray:
    """(replicates, sequences) float64 values of one metric; NaN where missing (or no KITTI segment)."""
    return metric_matrix(results_frame([column]), column, path, sequences)


def paired_samples(
    a: Column, b: Column, path: Sequence[str], sequences: Sequence[str]
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`samples` of A and B on the seeds both have, paired by seed: (S, sequences) each."""
    seeds = [s for s in a.replicates if s in b.replicates]
    x = samples(a, path, sequences)[[a.replicates.index(s) for s in seeds]]
    return x, samples(b, path, sequences)[[b.replicates.index(s) for s in seeds]]


def evaluated_sequences(columns: Sequence[Column], among: Sequence[str] | None = None) -> list[str]:
    """The sequences some replicate of ``columns`` has results for: sorted, or in ``among``'s order."""
    evaluated = {name for c in columns for per_sequence in c.results for name in per_sequence}
    return sorted(evaluated) if among is None else [s for s in among if s in evaluated]


def seed_scores(column: Column, path: Sequence[str], sequences: Sequence[str]) -> dict[str, float]:
    """``{replicate: mean over sequences}`` of one metric; a seed missing a sequence is left out."""
    values = samples(column, path, sequences)  # (seeds, sequences)
    means = values.mean(axis=1) if values.shape[1] else np.full(len(values), np.nan)
    return {r: float(m) for r, m in zip(column.replicates, means, strict=True) if math.isfinite(m)}


@dataclass
class Cell:
    """A table cell: mean over replicates, sample std (ddof = 1; NaN for n < 2), n, bold flag."""

    mean: float
    std: float
    n: int
    best: bool = False

    @classmethod
    def of(cls, values: Sequence[float | None] | np.ndarray) -> Cell:
        """The cell of ``values`` (None or NaN: missing)."""
        values = np.asarray(values, dtype=np.float64)
        finite = values[np.isfinite(values)]
        if finite.size == 0:
            return cls(math.nan, math.nan, 0)
        std = float(np.std(finite, ddof=1)) if finite.size > 1 else math.nan
        return cls(float(np.mean(finite)), std, int(finite.size))

    def csv(self) -> list[object]:
        """Mean and std at full precision (empty where undefined), and n."""
        return [repr(self.mean) if self.n else "", repr(self.std) if self.n > 1 else "", self.n]


@dataclass
class Table:
    """A filled table: ``cells[row][column][metric]``, rows the sequences then :data:`MEAN_ROW`; ``notes``
    ``{row: note}`` shown beside its name (a last column in CSV)."""

    spec: TableSpec
    columns: list[Column]
    rows: list[str]
    cells: list[list[list[Cell]]]
    mean_over: list[str]
    notes: dict[str, str] = field(default_factory=dict)


def build_table(
    spec: TableSpec,
    columns: Sequence[Column],
    sequences: Sequence[str],
    notes: Mapping[str, str] | None = None,
    frame: pd.DataFrame | None = None,
) -> Table:
    """Cells per sequence, a mean row and the bold marks; ``frame``: the columns'
    :func:`~lossvo.report.frame.results_frame` (made here if None). The mean row averages each replicate
    over the sequences where every column has a value, then takes mean ± std over the replicates."""
    frame = results_frame(columns) if frame is None else frame
    k = len(spec.metrics)
    data = [metric_matrix(frame, c, path, sequences) for c in columns for _, path in spec.metrics]
    common = [j for j in range(len(sequences)) if all(np.isfinite(d[:, j]).any() for d in data)]
    means = [d[:, common].mean(axis=1) if common else np.full(len(d), np.nan) for d in data]
    by_row = [[d[:, s] for d in data] for s in range(len(sequences))] + [means]  # [row][column * k + metric]
    cells = [[[Cell.of(v) for v in row[c * k : (c + 1) * k]] for c in range(len(columns))] for row in by_row]
    shown = np.array([[[cell.mean for cell in col] for col in row] for row in cells])  # (rows, columns, k)
    best = shown == np.fmin.reduce(shown, axis=1, keepdims=True)  # each row and metric's minimum, NaN left
    for cell, bold in zip((cell for row in cells for col in row for cell in col), best.ravel(), strict=True):
        cell.best = bool(bold)
    notes = {s: n for s, n in (notes or {}).items() if s in sequences}
    return Table(spec, list(columns), [*sequences, MEAN_ROW], cells, [sequences[j] for j in common], notes)


def fmt(x: float, digits: int = 4) -> str:
    """A number with ``digits`` significant digits, fixed-point (no exponent between 1e-4 and 1e6)."""
    if not math.isfinite(x):
        return "n/a"
    if x == 0:
        return "0"
    if not 1e-4 <= abs(x) < 1e6:
        return f"{x:.{digits - 1}e}"
    decimals = max(0, digits - 1 - math.floor(math.log10(abs(x))))
    return f"{x:.{decimals}f}"


def mean_std_text(cell: Cell, digits: int = 4, replicated: bool = True) -> str:
    """``"mean ± std"`` of a cell, the mean ``**bold**`` where best (``"mean"`` for n = 1 or where not
    ``replicated``, ``"n/a"`` for n = 0)."""
    if cell.n == 0:
        return "n/a"
    text = f"**{fmt(cell.mean, digits)}**" if cell.best else fmt(cell.mean, digits)
    return text + (f" ± {fmt(cell.std, 2)}" if replicated and cell.n > 1 else "")


def table_rows(table: Table, mean_name: str = "**mean**") -> Rows:
    """The table as text cells, a row named with its note (``11 (unseen motion)``), the mean row
    ``mean_name``."""
    replicated = any(len(c.replicates) > 1 for c in table.columns)
    header = ["sequence"] + [f"{c.label}: {name}" for c in table.columns for name, _ in table.spec.metrics]
    rows: list[list[object]] = []
    for row, cells in zip(table.rows, table.cells, strict=True):
        name = mean_name if row == MEAN_ROW else f"{row} ({table.notes[row]})" if row in table.notes else row
        rows.append([name, *(mean_std_text(cell, replicated=replicated) for col in cells for cell in col)])
    return Rows(header, rows)


def table_csv(table: Table) -> str:
    """The table as CSV: per column and metric mean, std and n at full precision, then ``note``."""
    metrics = [f"{c.label} | {name}" for c in table.columns for name, _ in table.spec.metrics]
    header = ["sequence", *(f"{m}{part}" for m in metrics for part in ("", " std", " n")), "note"]
    rows: list[list[object]] = []
    for row, cells in zip(table.rows, table.cells, strict=True):
        values = [x for col in cells for cell in col for x in cell.csv()]
        rows.append([row, *values, table.notes.get(row, "")])
    return table_render.csv_text(Rows(header, rows))


def table_latex(table: Table) -> str:
    """The table as a LaTeX ``tabular`` with booktabs rules."""
    rows = table_rows(table, mean_name="Mean")
    k = len(table.spec.metrics)
    latex = Rows(["", *(name for _ in table.columns for name, _ in table.spec.metrics)], rows.rows)
    groups = [("Sequence", 1), *((c.label, k) for c in table.columns)]
    return table_render.latex(latex, table.spec.title, groups, rule_before={table.rows.index(MEAN_ROW)})
