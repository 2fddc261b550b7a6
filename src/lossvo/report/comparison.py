"""The pairwise comparison of configurations: every pair (of one architecture, where the sweep varies it)
on the APE / RPE RMSEs, paired over (seed, sequence), with the report's paired test
(:func:`lossvo.report.statistics.paired_test`; rows of ``tables/pairwise.csv`` and of its section of
report.md)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from lossvo.report.configurations import UNKNOWN_ARCHITECTURE, architecture_groups
from lossvo.report.jobs import APE_TRANS, RPE_ROT, RPE_TRANS, metric_value
from lossvo.report.render import Rows, prepend_column
from lossvo.report.statistics import ALPHA, PairedTest, paired_test
from lossvo.report.tables import NETWORK, Column, fmt

COMPARED = (
    ("APE trans RMSE [m]", APE_TRANS),
    ("RPE trans RMSE [m]", RPE_TRANS),
    ("RPE rot RMSE [rad]", RPE_ROT),
)


@dataclass
class Comparison:
    """A vs B on one metric over paired (seed, sequence) values (``test.median_diff``: A - B in the
    metric's unit; ``test.lower``: pairs where A is lower), on ``seeds`` common seeds; ``architecture``:
    A's (and B's)."""

    a: str
    b: str
    metric: str
    test: PairedTest
    seeds: int
    architecture: str | None = None

    @property
    def verdict(self) -> str:
        if self.test.n == 0:
            return "n/a (no common seed and sequence)"
        if self.seeds < 2:
            return "n/a (one seed: no seed-noise estimate)"
        return "yes" if self.test.p_value < ALPHA else "no"


def paired_values(a: Column, b: Column, path: Sequence[str]) -> tuple[np.ndarray, np.ndarray, int]:
    """Values of A and B on the (seed, sequence) pairs both have: (P,), (P,) and the number of seeds."""
    seeds = [s for s in a.replicates if s in b.replicates]
    xs, ys = [], []
    for seed in seeds:
        ra, rb = a.results[a.replicates.index(seed)], b.results[b.replicates.index(seed)]
        for name in ra:
            x, y = metric_value(ra[name], path), metric_value(rb.get(name), path)
            if x is not None and y is not None:
                xs.append(x)
                ys.append(y)
    return np.array(xs), np.array(ys), len(seeds)


def compare(columns: Sequence[Column], by_architecture: bool = False) -> list[Comparison]:
    """Every pair of network columns on each metric of :data:`COMPARED`; with ``by_architecture`` every
    pair of one architecture, architecture by architecture."""
    networks = [c for c in columns if c.kind == NETWORK]
    groups = architecture_groups(networks).values() if by_architecture else [networks]
    out = []
    for group in groups:
        for a, b in combinations(group, 2):
            for metric, path in COMPARED:
                x, y, seeds = paired_values(a, b, path)
                test = paired_test(b.label, x, y)
                out.append(Comparison(a.label, b.label, metric, test, seeds, a.architecture))
    return out


def _with_architecture(table: Rows, comparisons: Sequence[Comparison], by_architecture: bool) -> Rows:
    if not by_architecture:
        return table
    return prepend_column(
        table, "architecture", [c.architecture or UNKNOWN_ARCHITECTURE for c in comparisons]
    )


def comparison_rows(comparisons: Sequence[Comparison], by_architecture: bool = False) -> Rows:
    """The section's table (with ``by_architecture`` an ``architecture`` column first)."""
    header = [
        "A",
        "B",
        "metric",
        "pairs",
        "median A − B",
        "A lower",
        "p (Wilcoxon)",
        f"distinguishable at {ALPHA}",
    ]
    rows: list[list[object]] = [
        [c.a, c.b, c.metric, c.test.n, fmt(c.test.median_diff), f"{c.test.lower}/{c.test.n}",
         fmt(c.test.p_value, 3), c.verdict]
        for c in comparisons
    ]  # fmt: skip
    return _with_architecture(Rows(header, rows), comparisons, by_architecture)


def comparison_csv_rows(comparisons: Sequence[Comparison], by_architecture: bool = False) -> Rows:
    """``tables/pairwise.csv``: full precision (with ``by_architecture`` an ``architecture`` column first)."""
    header = ["a", "b", "metric", "pairs", "seeds", "median_diff", "a_lower", "p_value", "verdict"]
    rows: list[list[object]] = [
        [c.a, c.b, c.metric, c.test.n, c.seeds, repr(c.test.median_diff), c.test.lower, repr(c.test.p_value),
         c.verdict]
        for c in comparisons
    ]  # fmt: skip
    return _with_architecture(Rows(header, rows), comparisons, by_architecture)
