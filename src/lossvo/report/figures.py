"""Figures of a sweep report: loss curves, bird's-eye trajectories, APE bar chart, the claims' forest plot.

Each ``plot_*`` draws one PNG on a :func:`lossvo.evaluation.plots.new_figure` (sizes in inches) and saves it
atomically; matplotlib is imported only where a figure is drawn.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lossvo.evaluation import baselines
from lossvo.evaluation.plots import colors, new_figure, plot_birdseye, save_png
from lossvo.report import statistics
from lossvo.report.claims import CLAIM_ERRORS, Claim, loss_word
from lossvo.report.jobs import Job, read_trajectory
from lossvo.report.tables import BASELINE, Column, Table, seed_scores

if TYPE_CHECKING:
    from matplotlib.axes import Axes

CURVE_PANELS = (
    ("validation score (loss-independent)", "score", False),
    ("total loss", "loss", True),
    ("translation loss (unweighted)", "trans_loss", True),
    ("rotation loss (unweighted)", "rot_loss", True),
    ("rotation error (rad)", "rot_err_rad", False),
    ("translation error (m)", "trans_err_m", False),
)
"""The curves figure's panels: (title, metrics.csv key without ``train/`` or ``val/``, log scale allowed)."""
CURVE_COLUMNS = 3


def curve_band(jobs: Sequence[Job], key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Epochs (E,), mean (E,) and sample std (E,) of a metrics.csv column over the jobs, on their common
    epochs; None if none."""
    series = [j.curves.series[key] for j in jobs if j.curves is not None and key in j.curves.series]
    if not series:
        return None
    epochs = functools.reduce(np.intersect1d, (e for e, _ in series))
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
    """Per-epoch curves per configuration (mean ± std over seeds), a panel per :data:`CURVE_PANELS` entry;
    False if no job has curves."""
    from matplotlib.ticker import MaxNLocator

    rows = -(-len(CURVE_PANELS) // CURVE_COLUMNS)
    fig = new_figure(4.2 * CURVE_COLUMNS, 3.4 * rows)
    axes = fig.subplots(rows, CURVE_COLUMNS, squeeze=False).ravel()
    for ax in axes[len(CURVE_PANELS) :]:
        ax.set_axis_off()
    axes = axes[: len(CURVE_PANELS)]
    drawn = False
    for column, color in zip(columns, colors(len(columns)), strict=True):
        for ax, (_, key, _) in zip(axes, CURVE_PANELS, strict=True):
            drawn |= _draw_bands(ax, column, key, color)
    for ax, (title, _, log_scale) in zip(axes, CURVE_PANELS, strict=True):
        ax.set_title(title)
        ax.set_xlabel("epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(True, alpha=0.3)
        if log_scale and _spans_decades(ax):
            ax.set_yscale("log")
    if drawn:
        axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
        save_png(fig, path)
    return drawn


def _draw_bands(ax: Axes, column: Column, key: str, color: Any) -> bool:
    """The train (solid) and val (dashed) curves of one key of a configuration; whether any was drawn."""
    drawn = False
    for split, style in (("train", "-"), ("val", "--")):
        band = curve_band(column.jobs, f"{split}/{key}")
        if band is None:
            continue
        epochs, mean, std = band
        ax.plot(epochs + 1, mean, style, color=color, marker="o", ms=3, label=f"{column.label} ({split})")
        if np.isfinite(std).any():
            ax.fill_between(epochs + 1, mean - std, mean + std, color=color, alpha=0.15, lw=0)
        drawn = True
    return drawn


BASELINE_STYLES = {
    baselines.MEAN: {"color": "0.45"},
    baselines.ORB: {"color": "tab:olive"},
    baselines.OWN: {"color": "tab:cyan"},
    baselines.FLOW: {"color": "tab:purple"},
}
"""Colours of the baselines' dashed lines in the trajectory figures (any other: light grey)."""


def plot_trajectories(
    sequence: str,
    columns: Sequence[Column],
    gt: np.ndarray | None,
    extra: Mapping[str, np.ndarray],
    path: Path,
) -> None:
    """Bird's-eye view of one sequence: ``gt`` (N, 4, 4), each configuration's first seed and the baselines
    in ``extra`` (name -> (N, 4, 4)) dashed."""
    trajectories: dict[str, np.ndarray] = {}
    styles: dict[str, dict[str, Any]] = {}
    for column, color in zip(columns, colors(len(columns)), strict=True):
        est = read_trajectory(column.jobs[0], sequence)
        if est is not None:
            label = f"{column.label} ({column.replicates[0]})"
            trajectories[label], styles[label] = est, {"color": color}
    for name, est in extra.items():
        style = BASELINE_STYLES.get(name, {"color": "0.7"})
        trajectories[name], styles[name] = est, {**style, "linestyle": "--", "lw": 1.0}
    plot_birdseye(path, gt, trajectories, f"sequence {sequence}", styles)


def plot_ape_bars(table: Table, path: Path) -> None:
    """Grouped bars of Table I's APE (m) per row and column, error bars the sample std over seeds."""
    fig = new_figure(min(16.0, 3.0 + 0.12 * len(table.rows) * max(1, len(table.columns))), 4.2)
    ax = fig.add_subplot()
    width = 0.8 / max(1, len(table.columns))
    x = np.arange(len(table.rows))
    for c, (column, color) in enumerate(zip(table.columns, colors(len(table.columns)), strict=True)):
        cells = [row[c][0] for row in table.cells]
        means = np.array([cell.mean for cell in cells])
        stds = np.array([cell.std if cell.n > 1 else 0.0 for cell in cells])
        style = {"color": color, "hatch": "//" if column.kind == BASELINE else None, "label": column.label}
        ax.bar(x + (c - (len(table.columns) - 1) / 2) * width, means, width, yerr=stds, capsize=2, **style)
    ax.set_xticks(x, table.rows)
    ax.set_xlabel("sequence")
    ax.set_ylabel("APE translation RMSE (m)")
    if np.isfinite([row[c][0].mean for row in table.cells for c in range(len(table.columns))]).any():
        ax.set_yscale("log")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    save_png(fig, path)


SeedValues = dict[str, dict[str, float]]
"""``{quantity: {seed: value}}`` of one configuration."""


def forest_rows(claim: Claim, columns: Mapping[str, Column]) -> list[tuple[str, SeedValues]]:
    """Claim (a)'s configurations, the claimed one first, each with the per-seed values it tests."""
    labels = [claim.configuration, *(t.versus for t in claim.quantities[0].tests)]
    return [
        (label, {q: seed_scores(columns[label], path, claim.sequences) for q, path in CLAIM_ERRORS})
        for label in labels
    ]


def plot_forest(claims: Sequence[Claim], columns: Sequence[Column], path: Path) -> bool:
    """The forest plot of claim (a), a column per :data:`CLAIM_ERRORS` metric (docs/report.md); False if no
    claim (a) was tested."""
    tested = [c for c in claims if c.letter == "a" and not c.untested and c.quantities]
    if not tested:
        return False
    by_label = {c.label: c for c in columns}
    blocks = [(c, forest_rows(c, by_label)) for c in tested]
    n_top = sum(len(rows) for _, rows in blocks)
    n_bottom = n_top - len(blocks)
    fig = new_figure(4.6 * len(CLAIM_ERRORS) + 2.5, 2.4 + 0.45 * (n_top + n_bottom))
    ratios = {"height_ratios": [n_top, max(n_bottom, 1)]}
    axes = fig.subplots(2, len(CLAIM_ERRORS), squeeze=False, gridspec_kw=ratios)
    for col, (quantity, _) in enumerate(CLAIM_ERRORS):
        _forest_column(axes[0][col], axes[1][col], blocks, quantity, show=col == 0)
    margin = f"{100 * tested[0].margin:g} %"
    fig.suptitle(
        "Held-out error per seed (dots) with the mean and its 95 % interval; below, "
        f"({loss_word(tested[0].claimed_loss)} − other) / "
        f"other per seed with the mean and its 90 % interval, ±{margin} shaded, and each verdict",
        fontsize=9,
    )
    save_png(fig, path)
    return True


def _row_label(claim: Claim, label: str) -> str:
    return f"{claim.architecture}: {label}" if claim.architecture else label


def _rows_axis(ax: Axes, labels: Sequence[str], show_labels: bool) -> None:
    ax.set_yticks([-i for i in range(len(labels))], labels if show_labels else [""] * len(labels))
    ax.set_ylim(-len(labels) + 0.4, 0.6)
    ax.grid(True, axis="x", alpha=0.3)


def _dots_and_interval(ax: Axes, values: np.ndarray, y: float, confidence: float, color: Any) -> None:
    """Values (n,) as dots on row y, and their mean with its t-interval at ``confidence`` just below."""
    ax.scatter(values, np.full(values.size, y), s=14, color=color, alpha=0.6, lw=0)
    if not values.size:
        return
    low, high = statistics.t_interval(values, confidence)
    if math.isfinite(low):
        ax.plot([low, high], [y - 0.25, y - 0.25], color=color, lw=2)
    ax.scatter([values.mean()], [y - 0.25], marker="D", s=28, color=color, edgecolor="black", lw=0.5)


def _forest_column(
    top: Axes,
    bottom: Axes,
    blocks: Sequence[tuple[Claim, list[tuple[str, SeedValues]]]],
    quantity: str,
    show: bool,
) -> None:
    """One quantity's column: the values per seed above, the relative differences to the claimed one below."""
    labels: tuple[list[str], list[str]] = ([], [])
    for claim, rows in blocks:
        ours = rows[0][1][quantity]
        decisions = next(q.decisions for q in claim.quantities if q.quantity == quantity)
        for i, ((label, values), color) in enumerate(zip(rows, colors(len(rows)), strict=True)):
            _dots_and_interval(top, np.array(list(values[quantity].values())), -len(labels[0]), 0.95, color)
            labels[0].append(_row_label(claim, label))
            if i == 0:
                continue
            seeds = [s for s in ours if s in values[quantity]]
            pairs = np.array([[ours[s], values[quantity][s]] for s in seeds]).reshape(-1, 2)
            r = 100 * statistics.relative_differences(pairs[:, 0], pairs[:, 1])
            y = -len(labels[1])
            _dots_and_interval(bottom, r, y, 1 - 2 * statistics.ALPHA, color)
            box = {"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8}
            bottom.annotate(decisions[i - 1].removesuffix(" at this n"), (0.99, y + 0.3),
                            xycoords=("axes fraction", "data"), fontsize=7, ha="right", va="center",
                            bbox=box)  # fmt: skip
            labels[1].append(_row_label(claim, f"{claim.configuration} vs {label}"))
    _rows_axis(top, labels[0], show)
    top.set_title(quantity)
    margin = 100 * blocks[0][0].margin
    bottom.axvspan(-margin, margin, color="tab:green", alpha=0.12, lw=0)
    bottom.axvline(0.0, color="0.4", lw=0.8)
    _rows_axis(bottom, labels[1], show)
    bottom.set_xlabel("relative difference (%)")
