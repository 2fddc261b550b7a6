"""How the predicted speed follows the true one on the slowest and the fastest stretches (by true step
length) of each sequence the networks were not trained on: per job the mean predicted over the mean true
step length, from its trajectory. See docs/report.md.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from lossvo.report.claims import training_sequences
from lossvo.report.configurations import varies_architecture
from lossvo.report.jobs import read_trajectory
from lossvo.report.tables import NETWORK, Cell, Column, fmt, mean_std_text, with_architecture
from lossvo.table_render import Rows

SHARE = 0.2
"""Fraction of a sequence's frame pairs in each of its slow and fast stretches."""
STRETCHES = ("slowest", "fastest", "all")

SPEED_TITLE = "Speed on the slowest and fastest stretches"
SPEED_TEXT = (
    f"Frame pairs ranked by their true step length: the slowest and the fastest {100 * SHARE:.0f} % of a "
    "sequence's pairs, and all of them. *true*: their mean true step length [m a frame]; *predicted / true*: "
    "the mean predicted step length over the mean true one (1: right on average; above 1: too fast), "
    "mean ± std over seeds. Sequences the networks were not trained on."
)


def step_lengths(poses: np.ndarray) -> np.ndarray:
    """(N - 1,) metres: the length of each relative translation of a trajectory ``poses`` (N, 4, 4)."""
    relative = np.linalg.solve(poses[:-1], poses[1:])
    return np.linalg.norm(relative[:, :3, 3], axis=-1)


def stretches(true: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks (N,) of the slowest and fastest :data:`SHARE` of pairs by true step length, and all."""
    order = np.argsort(true, kind="stable")
    k = max(1, round(SHARE * len(true)))
    slow, fast = np.zeros(len(true), bool), np.zeros(len(true), bool)
    slow[order[:k]], fast[order[-k:]] = True, True
    return {"slowest": slow, "fastest": fast, "all": np.ones(len(true), bool)}


def speed_ratios(estimate: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """Stretch -> mean predicted over mean true step length of ``estimate`` and ``gt`` (N, 4, 4), m."""
    true, predicted = step_lengths(gt), step_lengths(estimate)
    return {name: float(predicted[m].mean() / true[m].mean()) for name, m in stretches(true).items()}


def speed_rows(networks: Sequence[Column], gt: Mapping[str, np.ndarray], sequences: Sequence[str]) -> Rows:
    """Per configuration and held-out sequence: each stretch's true step length and ratio over seeds."""
    outside = [s for s in sequences if s in gt and s not in training_sequences(networks)]
    header = ["configuration", "sequence"]
    header += [f"{name}: {what}" for name in STRETCHES for what in ("true [m]", "predicted / true")]
    rows = [
        [c.architecture, c.label, s, *_cells(c, s, gt[s])]
        for c in networks
        if c.kind == NETWORK
        for s in outside
    ]
    return with_architecture(header, rows, varies_architecture(networks))


def _cells(column: Column, sequence: str, gt: np.ndarray) -> list[str]:
    """Per stretch the true step length and the ratio over the seeds whose trajectory matches ``gt``."""
    true = step_lengths(gt)
    masks = stretches(true)
    found = (read_trajectory(job, sequence) for job in column.jobs)
    ratios = [speed_ratios(t, gt) for t in found if t is not None and len(t) == len(gt)]
    cells: list[str] = []
    for name in STRETCHES:
        cell = Cell.of([r[name] for r in ratios])
        cells += [fmt(float(true[masks[name]].mean()), 3), mean_std_text(cell, 3)]
    return cells
