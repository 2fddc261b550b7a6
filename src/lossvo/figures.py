"""Figures of a sweep report (:mod:`lossvo.report`): loss curves, bird's-eye trajectories, APE bar chart.

Each ``plot_*`` function draws one PNG (100 dpi, sizes in inches) with matplotlib's Agg canvas and no
pyplot state, and saves it atomically (:func:`save_figure`). matplotlib is imported inside the functions,
so a report without figures never loads it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lossvo.atomic import atomic_path
from lossvo.tables import BASELINE, Column, Table

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from lossvo.report import Job

# The panels of the curves figure: (title, metrics.csv key without the ``train/`` or ``val/`` prefix,
# log scale allowed).
CURVE_PANELS = (
    ("validation score (loss-independent)", "score", False),
    ("total loss", "loss", True),
    ("translation loss (unweighted)", "trans_loss", True),
    ("rotation loss (unweighted)", "rot_loss", True),
    ("rotation error (rad)", "rot_err_rad", False),
    ("translation error (m)", "trans_err_m", False),
)
CURVE_COLUMNS = 3


def _figure(width: float, height: float) -> Figure:
    """An empty figure of ``width`` x ``height`` inches on an Agg canvas, tight layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="tight")  # laid out once, while saving
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: Path) -> None:
    """Save a figure as PNG at 100 dpi atomically (temp file in the same folder, then rename)."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100)


def _colors(n: int) -> list[Any]:
    """``n`` RGBA colours of the tab10 colour map (repeating after 10)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(i % 10) for i in range(n)]


def curve_band(jobs: Sequence[Job], key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Epochs (E,), mean (E,) and sample std (E,) (NaN for one seed) of a metrics.csv column over the
    jobs' seeds, on the epochs all of them logged; None if no job has it."""
    series = [j.curves.series[key] for j in jobs if j.curves is not None and key in j.curves.series]
    if not series:
        return None
    epochs = series[0][0]
    for e, _ in series[1:]:
        epochs = np.intersect1d(epochs, e)
    if epochs.size == 0:
        return None
    values = np.stack([v[np.searchsorted(e, epochs)] for e, v in series])
    std = values.std(axis=0, ddof=1) if len(values) > 1 else np.full(len(epochs), np.nan)
    return epochs, values.mean(axis=0), std


def _spans_decades(ax: Axes, ratio: float = 20.0) -> bool:
    """Whether the positive data of an axes' lines spans more than ``ratio`` (worth a log scale)."""
    values = np.concatenate(
        [np.asarray(line.get_ydata(), dtype=float) for line in ax.get_lines()] or [np.empty(0)]
    )
    values = values[np.isfinite(values) & (values > 0)]
    return values.size > 1 and values.max() > ratio * values.min()


def plot_curves(columns: Sequence[Column], path: Path) -> bool:
    """Score, loss and yardstick curves per configuration, one panel per :data:`CURVE_PANELS` entry
    (:data:`CURVE_COLUMNS` panels a row).

    x: epoch (1-based); y: the validation score ``val/score`` (unitless, the same for every loss), the
    losses (unitless, the translation and rotation terms unweighted), rotation error (rad) and translation
    error (m) as logged in metrics.csv. Train solid, val dashed; the line is the mean over seeds, the band
    mean ± 1 sample std (none for one seed); log scale where a loss panel spans decades. A panel whose
    column no job logged stays empty. Returns False (and writes nothing) when no job has curves.
    """
    from matplotlib.ticker import MaxNLocator

    rows = -(-len(CURVE_PANELS) // CURVE_COLUMNS)
    fig = _figure(4.2 * CURVE_COLUMNS, 3.4 * rows)
    axes = fig.subplots(rows, CURVE_COLUMNS, squeeze=False).ravel()
    for ax in axes[len(CURVE_PANELS) :]:
        ax.set_axis_off()
    axes = axes[: len(CURVE_PANELS)]
    drawn = False
    for column, color in zip(columns, _colors(len(columns)), strict=True):
        for ax, (_, key, _) in zip(axes, CURVE_PANELS, strict=True):
            for split, style in (("train", "-"), ("val", "--")):
                band = curve_band(column.jobs, f"{split}/{key}")
                if band is None:
                    continue
                epochs, mean, std = band
                ax.plot(
                    epochs + 1, mean, style, color=color, marker="o", ms=3, label=f"{column.label} ({split})"
                )
                if np.isfinite(std).any():
                    ax.fill_between(epochs + 1, mean - std, mean + std, color=color, alpha=0.15, lw=0)
                drawn = True
    for ax, (title, _, log_scale) in zip(axes, CURVE_PANELS, strict=True):
        ax.set_title(title)
        ax.set_xlabel("epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(True, alpha=0.3)
        if log_scale and _spans_decades(ax):
            ax.set_yscale("log")
    if drawn:
        axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
        save_figure(fig, path)
    return drawn


def read_trajectory(job: Job, sequence: str) -> np.ndarray | None:
    """A job's estimated trajectory (N, 4, 4), translation in m, of one sequence; None if missing or
    unreadable."""
    from lossvo.data.kitti import KittiFormatError, read_poses

    entry = job.results["sequences"].get(sequence, {}) if job.results else {}
    try:
        return read_poses(job.path / entry.get("trajectory", f"trajectories/{sequence}.txt"))
    except (KittiFormatError, OSError):
        return None


def plot_trajectories(
    sequence: str, columns: Sequence[Column], gt: np.ndarray | None, extra: dict[str, np.ndarray], path: Path
) -> None:
    """Bird's-eye view of one sequence: x (m) right, z (m) forward, equal axes.

    Draws the ground truth ``gt`` (N, 4, 4) in black with its start marked, each configuration's
    trajectory of its first seed (read from the job folder), and the baselines' trajectories in ``extra``
    (name -> (N, 4, 4)) dashed.
    """
    fig = _figure(6.5, 6.5)
    ax = fig.add_subplot()
    if gt is not None:
        ax.plot(gt[:, 0, 3], gt[:, 2, 3], color="black", lw=2.0, label="ground truth")
    for column, color in zip(columns, _colors(len(columns)), strict=True):
        est = read_trajectory(column.jobs[0], sequence)
        if est is not None:
            ax.plot(
                est[:, 0, 3],
                est[:, 2, 3],
                color=color,
                lw=1.2,
                label=f"{column.label} ({column.replicates[0]})",
            )
    for (name, est), color in zip(extra.items(), ("0.45", "tab:olive", "tab:cyan"), strict=False):
        ax.plot(est[:, 0, 3], est[:, 2, 3], "--", color=color, lw=1.0, label=name)
    start = gt[0] if gt is not None else None
    if start is not None:
        ax.plot(start[0, 3], start[2, 3], "o", color="tab:green", ms=5, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title(f"sequence {sequence}")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    save_figure(fig, path)


def plot_ape_bars(table: Table, path: Path) -> None:
    """Grouped bars of the first metric of ``table`` (APE translation RMSE, m, of Table I) per sequence
    and the mean row, one bar per column (baselines hatched), error bars = sample std over seeds; log
    scale."""
    fig = _figure(min(16.0, 3.0 + 0.12 * len(table.rows) * max(1, len(table.columns))), 4.2)
    ax = fig.add_subplot()
    width = 0.8 / max(1, len(table.columns))
    x = np.arange(len(table.rows))
    for c, (column, color) in enumerate(zip(table.columns, _colors(len(table.columns)), strict=True)):
        cells = [row[c][0] for row in table.cells]
        means = np.array([cell.mean for cell in cells])
        stds = np.array([cell.std if cell.n > 1 else 0.0 for cell in cells])
        ax.bar(
            x + (c - (len(table.columns) - 1) / 2) * width,
            means,
            width,
            yerr=stds,
            color=color,
            hatch="//" if column.kind == BASELINE else None,
            label=column.label,
            capsize=2,
        )
    ax.set_xticks(x, table.rows)
    ax.set_xlabel("sequence")
    ax.set_ylabel("APE translation RMSE (m)")
    if np.isfinite([row[c][0].mean for row in table.cells for c in range(len(table.columns))]).any():
        ax.set_yscale("log")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    save_figure(fig, path)
