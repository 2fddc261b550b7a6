"""The pairwise comparison of configurations: every pair on the APE / RPE RMSEs, paired over
(seed, sequence), with a two-sided Wilcoxon signed-rank test (``tables/pairwise.csv`` and its section of
report.md)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from lossvo.report.jobs import APE_TRANS, RPE_ROT, RPE_TRANS, lookup
from lossvo.report.statistics import wilcoxon_p
from lossvo.report.tables import NETWORK, Column, fmt, md

SIGNIFICANCE = 0.05
COMPARED = (
    ("APE trans RMSE [m]", APE_TRANS),
    ("RPE trans RMSE [m]", RPE_TRANS),
    ("RPE rot RMSE [rad]", RPE_ROT),
)


@dataclass
class Comparison:
    """A vs B on one metric over paired (seed, sequence) values: ``median_diff`` of A - B (in the
    metric's unit), the count of pairs where A is lower, and the two-sided Wilcoxon signed-rank p-value."""

    a: str
    b: str
    metric: str
    n: int
    median_diff: float
    a_lower: int
    p_value: float
    seeds: int

    @property
    def verdict(self) -> str:
        if self.n == 0:
            return "n/a (no common seed and sequence)"
        if self.seeds < 2:
            return "n/a (one seed: no seed-noise estimate)"
        return "yes" if self.p_value < SIGNIFICANCE else "no"


def paired_values(a: Column, b: Column, path: Sequence[str]) -> tuple[np.ndarray, np.ndarray, int]:
    """Values of A and B on the (seed, sequence) pairs both have: (P,), (P,) and the number of seeds."""
    seeds = [s for s in a.replicates if s in b.replicates]
    xs, ys = [], []
    for seed in seeds:
        ra, rb = a.results[a.replicates.index(seed)], b.results[b.replicates.index(seed)]
        for name in ra:
            x, y = lookup(ra[name], path), lookup(rb.get(name), path)
            if isinstance(x, (int, float)) and isinstance(y, (int, float)):
                xs.append(float(x))
                ys.append(float(y))
    return np.array(xs), np.array(ys), len(seeds)


def compare_pair(a: Column, b: Column, metric: str, path: Sequence[str]) -> Comparison:
    """A against B on the metric at ``path`` of their sequence entries."""
    x, y, seeds = paired_values(a, b, path)
    d = x - y
    p = wilcoxon_p(d) if d.size else math.nan
    median = float(np.median(d)) if d.size else math.nan
    return Comparison(a.label, b.label, metric, int(d.size), median, int((d < 0).sum()), p, seeds)


def compare(columns: Sequence[Column]) -> list[Comparison]:
    """Every pair of network columns on each metric of :data:`COMPARED`."""
    networks = [c for c in columns if c.kind == NETWORK]
    return [
        compare_pair(a, b, metric, path) for a, b in combinations(networks, 2) for metric, path in COMPARED
    ]


def comparisons_markdown(comparisons: Sequence[Comparison]) -> str:
    header = "| A | B | metric | pairs | median A − B | A lower | p (Wilcoxon) | distinguishable at 0.05 |"
    lines = [header, "|" + "---|" * 8]
    for c in comparisons:
        lines.append(
            f"| {md(c.a)} | {md(c.b)} | {c.metric} | {c.n} | {fmt(c.median_diff)} | {c.a_lower}/{c.n} | "
            f"{fmt(c.p_value, 3)} | {c.verdict} |"
        )
    return "\n".join(lines)


def comparisons_csv(comparisons: Sequence[Comparison]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["a", "b", "metric", "pairs", "seeds", "median_diff", "a_lower", "p_value", "verdict"])
    for c in comparisons:
        writer.writerow(
            [c.a, c.b, c.metric, c.n, c.seeds, repr(c.median_diff), c.a_lower, repr(c.p_value), c.verdict]
        )
    return out.getvalue()
