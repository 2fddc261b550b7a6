"""Tables of a sweep report: per-sequence metric tables and their text forms.

A :class:`Column` is one compared configuration (its seeds) or one baseline; :func:`build_table` fills a
:class:`Table` of :data:`TABLES` with mean ± sample std over seeds per sequence plus a mean row, and bolds
the minimum of each row; :func:`table_markdown`, :func:`table_csv` and :func:`table_latex` write it out.
A row may carry a note (e.g. ``unseen motion``): in markdown and LaTeX it follows the sequence name in
parentheses, in CSV it has its own last column, so the ``sequence`` column stays the bare name.
Units are those of the metrics: m and rad for APE / RPE, % and deg/100 m for the KITTI errors.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lossvo.report.jobs import APE_ROT, APE_TRANS, KITTI_R, KITTI_T, RPE_ROT, RPE_TRANS, Job, lookup

NETWORK, BASELINE = "network", "baseline"
MEAN_ROW = "mean"


@dataclass
class Column:
    """One compared configuration (network) or baseline: its replicates' per-sequence metrics.

    ``results[i]`` is ``{sequence: {"ape": ..., "rpe": ..., "kitti": ...}}`` of replicate ``i`` (a seed),
    ``replicates[i]`` its name; ``kind`` is :data:`NETWORK` or :data:`BASELINE`; ``jobs`` are a network's
    job folders in replicate order (none for a baseline).
    """

    label: str
    kind: str
    replicates: list[str]
    results: list[dict[str, dict[str, Any]]]
    jobs: list[Job] = field(default_factory=list)


# --------------------------------------------------------------------------------------------------
# Building: specs, cells, the mean row, bold marks
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TableSpec:
    """What a table holds: ``metrics`` are (header, path into a sequence's results entry)."""

    key: str
    title: str
    metrics: tuple[tuple[str, tuple[str, ...]], ...]


TABLES = (
    TableSpec(
        "translation",
        "Table I: translation RMSE (m)",
        (("APE [m]", APE_TRANS), ("RPE [m]", RPE_TRANS)),
    ),
    TableSpec(
        "rotation",
        "Table II: rotation RMSE (rad)",
        (("APE [rad]", APE_ROT), ("RPE [rad]", RPE_ROT)),
    ),
    TableSpec(
        "kitti",
        "Table III: KITTI odometry error (mean over 100-800 m segments)",
        (("t_err [%]", KITTI_T), ("r_err [deg/100m]", KITTI_R)),
    ),
)


def samples(column: Column, path: Sequence[str], sequences: Sequence[str]) -> np.ndarray:
    """(replicates, sequences) float64 values of one metric; NaN where missing (or no KITTI segment)."""
    out = np.full((len(column.results), len(sequences)), np.nan)
    for i, per_sequence in enumerate(column.results):
        for j, name in enumerate(sequences):
            value = lookup(per_sequence.get(name), path)
            out[i, j] = float(value) if isinstance(value, (int, float)) else np.nan
    return out


@dataclass
class Cell:
    """A table cell: mean over replicates, sample std (ddof = 1; NaN for n < 2), n, bold flag."""

    mean: float
    std: float
    n: int
    best: bool = False

    @classmethod
    def of(cls, values: np.ndarray) -> Cell:
        finite = values[np.isfinite(values)]
        if finite.size == 0:
            return cls(math.nan, math.nan, 0)
        std = float(np.std(finite, ddof=1)) if finite.size > 1 else math.nan
        return cls(float(np.mean(finite)), std, int(finite.size))


@dataclass
class Table:
    """A filled table: ``cells[row][column][metric]``; rows are the sequences, then :data:`MEAN_ROW`;
    ``notes`` maps a row to a short note shown beside its name."""

    spec: TableSpec
    columns: list[Column]
    rows: list[str]
    cells: list[list[list[Cell]]]
    mean_over: list[str]
    notes: dict[str, str] = field(default_factory=dict)

    def label(self, row: str) -> str:
        """A row's name with its note: ``"11 (unseen motion)"``; the bare name without one."""
        return f"{row} ({self.notes[row]})" if row in self.notes else row


def build_table(
    spec: TableSpec,
    columns: Sequence[Column],
    sequences: Sequence[str],
    notes: Mapping[str, str] | None = None,
) -> Table:
    """Cells per sequence, a mean row and the bold marks; ``notes``: {sequence: note} (:attr:`Table.notes`).

    The mean row averages each replicate over the sequences where every column has a value (so all
    columns are averaged over the same sequences), then takes mean ± std over the replicates.
    """
    data = [[samples(c, path, sequences) for _, path in spec.metrics] for c in columns]  # (rep, seq) each
    cells = [
        [[Cell.of(data[c][m][:, s]) for m in range(len(spec.metrics))] for c in range(len(columns))]
        for s in range(len(sequences))
    ]
    common = [
        j
        for j in range(len(sequences))
        if all(
            np.isfinite(data[c][m][:, j]).any() for c in range(len(columns)) for m in range(len(spec.metrics))
        )
    ]
    mean_row = [
        [Cell.of(_replicate_means(data[c][m], common)) for m in range(len(spec.metrics))]
        for c in range(len(columns))
    ]
    table = Table(
        spec,
        list(columns),
        [*sequences, MEAN_ROW],
        [*cells, mean_row],
        [sequences[j] for j in common],
        {s: n for s, n in (notes or {}).items() if s in sequences},
    )
    mark_best(table)
    return table


def _replicate_means(values: np.ndarray, common: Sequence[int]) -> np.ndarray:
    """(replicates,) mean of each replicate over the ``common`` sequences (NaN if one is missing)."""
    if not common:
        return np.full(len(values), np.nan)
    return values[:, list(common)].mean(axis=1)


def mark_best(table: Table) -> None:
    """Bold the minimum mean of each row and metric, over all columns (networks and baselines)."""
    for row in table.cells:
        for m in range(len(table.spec.metrics)):
            means = np.array([row[c][m].mean for c in range(len(table.columns))])
            if np.isfinite(means).any():
                best = np.nanmin(means)
                for c in range(len(table.columns)):
                    row[c][m].best = bool(means[c] == best)


# --------------------------------------------------------------------------------------------------
# Formatting: markdown, CSV, LaTeX
# --------------------------------------------------------------------------------------------------


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


def _cell_text(cell: Cell, bold: Callable[[str], str], pm: str, replicated: bool) -> str:
    if cell.n == 0:
        return "n/a"
    text = bold(fmt(cell.mean)) if cell.best else fmt(cell.mean)
    if replicated and cell.n > 1:
        text += f"{pm}{fmt(cell.std, 2)}"
    return text


def mean_std_text(cell: Cell, digits: int = 4) -> str:
    """``"mean ± std"`` of a cell (``"mean"`` for n = 1, ``"n/a"`` for n = 0), no bold."""
    if cell.n == 0:
        return "n/a"
    return fmt(cell.mean, digits) + (f" ± {fmt(cell.std, 2)}" if cell.n > 1 else "")


def _replicated(table: Table) -> bool:
    return any(len(c.replicates) > 1 for c in table.columns)


def md(text: str) -> str:
    """Text for a markdown table cell: one line, ``|`` escaped (it would end the cell)."""
    return " ".join(str(text).split()).replace("|", "\\|")


def table_markdown(table: Table) -> str:
    """The table as GitHub markdown, best cells in ``**bold**``."""
    replicated = _replicated(table)
    header = ["sequence"] + [
        f"{md(c.label)}: {name}" for c in table.columns for name, _ in table.spec.metrics
    ]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row, cells in zip(table.rows, table.cells, strict=True):
        texts = [_cell_text(cell, lambda s: f"**{s}**", " ± ", replicated) for col in cells for cell in col]
        lines.append(
            f"| {'**mean**' if row == MEAN_ROW else md(table.label(row))} | " + " | ".join(texts) + " |"
        )
    return "\n".join(lines)


def table_csv(table: Table) -> str:
    """The table as CSV: ``sequence``, then per column and metric ``<label> | <metric>`` (mean),
    ``... std`` (sample std, empty for n < 2) and ``... n``, then ``note`` (the row's note, or empty);
    full precision."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    header = ["sequence"]
    for c in table.columns:
        for name, _ in table.spec.metrics:
            header += [f"{c.label} | {name}", f"{c.label} | {name} std", f"{c.label} | {name} n"]
    writer.writerow([*header, "note"])
    for row, cells in zip(table.rows, table.cells, strict=True):
        values: list[str | int] = [row]
        for col in cells:
            for cell in col:
                values += [repr(cell.mean) if cell.n else "", repr(cell.std) if cell.n > 1 else "", cell.n]
        writer.writerow([*values, table.notes.get(row, "")])
    return out.getvalue()


LATEX_SPECIALS = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
}


def latex_escape(text: str) -> str:
    """``text`` with LaTeX's special characters escaped (:data:`LATEX_SPECIALS`)."""
    return "".join(LATEX_SPECIALS.get(ch, ch) for ch in text)


def table_latex(table: Table) -> str:
    """The table as a LaTeX ``tabular`` with booktabs rules; best cells in ``\\textbf``."""
    replicated = _replicated(table)
    k = len(table.spec.metrics)
    lines = [
        f"% {table.spec.title}; generated by python -m lossvo.report; needs \\usepackage{{booktabs}}",
        "\\begin{tabular}{l" + "r" * (k * len(table.columns)) + "}",
        "\\toprule",
        "Sequence & "
        + " & ".join(f"\\multicolumn{{{k}}}{{c}}{{{latex_escape(c.label)}}}" for c in table.columns)
        + " \\\\",
        "".join(f"\\cmidrule(lr){{{2 + i * k}-{1 + (i + 1) * k}}}" for i in range(len(table.columns))),
        " & "
        + " & ".join(latex_escape(name) for _ in table.columns for name, _ in table.spec.metrics)
        + " \\\\",
        "\\midrule",
    ]
    for row, cells in zip(table.rows, table.cells, strict=True):
        if row == MEAN_ROW:
            lines.append("\\midrule")
        texts = [
            _cell_text(cell, lambda s: f"\\textbf{{{s}}}", " $\\pm$ ", replicated)
            for col in cells
            for cell in col
        ]
        name = "Mean" if row == MEAN_ROW else latex_escape(table.label(row))
        lines.append(f"{name} & " + " & ".join(texts) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}"]
    return "\n".join(lines) + "\n"
