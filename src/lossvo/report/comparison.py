"""The pairwise comparison of configurations: every pair (of one architecture, where the sweep varies it)
on the APE / RPE RMSEs, seeds as the unit (each seed's mean over the evaluated sequences both have on every
paired seed, paired by seed), with the report's paired test (:func:`lossvo.report.statistics.paired_test`)
and Holm's correction over the pairs of one metric (rows of ``tables/pairwise.csv`` and of its section of
report.md)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import combinations

import numpy as np

from lossvo.report.configurations import architecture_groups
from lossvo.report.jobs import APE_TRANS, RPE_ROT, RPE_TRANS
from lossvo.report.statistics import ALPHA, PairedTest, can_decide, corrected, paired_test
from lossvo.report.tables import NETWORK, Column, fmt, paired_samples, with_architecture
from lossvo.table_render import Rows

COMPARED = (
    ("APE trans RMSE [m]", APE_TRANS),
    ("RPE trans RMSE [m]", RPE_TRANS),
    ("RPE rot RMSE [rad]", RPE_ROT),
)


@dataclass
class Comparison:
    """A vs B on one metric, paired by seed (``test.n`` seeds; ``test.mean_diff``: A - B in the metric's
    unit; ``test.lower``: seeds where A is lower; ``test.holm_p``: corrected over the pairs of this
    metric, ``comparisons`` of them), each seed's value its mean over the same ``sequences``;
    ``architecture``: A's (and B's)."""

    a: str
    b: str
    metric: str
    test: PairedTest
    sequences: list[str]
    comparisons: int = 1
    architecture: str | None = None

    @property
    def verdict(self) -> str:
        n = self.test.n
        if n == 0:
            return "n/a (no common seed with a common sequence)"
        if n < 2:
            return "n/a (one seed: no seed-noise estimate)"
        if not can_decide(n, self.comparisons):
            return f"cannot decide with {n} seeds"
        return "yes" if self.test.holm_p < ALPHA else "no"


def seed_pairs(
    a: Column, b: Column, path: Sequence[str], sequences: Sequence[str]
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Per-seed values of A and B on the S seeds both have, paired by seed: (S,), (S,), each seed's mean
    over those of ``sequences`` that both configurations have on every one of the S seeds (so every seed
    averages the same sequences), and those sequences."""
    x, y = paired_samples(a, b, path, sequences)  # (S, sequences)
    common = np.isfinite(x).all(axis=0) & np.isfinite(y).all(axis=0)
    if not len(x) or not common.any():
        return np.array([]), np.array([]), []
    used = [s for s, kept in zip(sequences, common, strict=True) if kept]
    return x[:, common].mean(axis=1), y[:, common].mean(axis=1), used


def compare(columns: Sequence[Column], by_architecture: bool = False) -> list[Comparison]:
    """Every pair of network columns on each metric of :data:`COMPARED`, over every sequence some job
    evaluated; Holm's correction over the pairs of one metric (of one architecture with
    ``by_architecture``, architecture by architecture)."""
    networks = [c for c in columns if c.kind == NETWORK]
    sequences = sorted({s for c in networks for r in c.results for s in r})
    groups = architecture_groups(networks).values() if by_architecture else [networks]
    out = []
    for group in groups:
        found = []
        for a, b in combinations(group, 2):
            for metric, path in COMPARED:
                x, y, used = seed_pairs(a, b, path, sequences)
                test = paired_test(b.label, x, y)
                found.append(Comparison(a.label, b.label, metric, test, used, architecture=a.architecture))
        for metric, _ in COMPARED:
            family = [i for i, c in enumerate(found) if c.metric == metric]
            tests = corrected([found[i].test for i in family])
            for i, test in zip(family, tests, strict=True):
                found[i] = replace(found[i], test=test, comparisons=len(family))
        out += found
    return out


def comparison_rows(comparisons: Sequence[Comparison], by_architecture: bool = False) -> Rows:
    """The section's table (with ``by_architecture`` an ``architecture`` column first)."""
    header = ["A", "B", "metric", "seeds", "mean A − B", "A lower", "p", "Holm p",
              f"distinguishable at {ALPHA}"]  # fmt: skip
    rows: list[list[object]] = []
    for c in comparisons:
        t = c.test
        numbers = [fmt(t.mean_diff), f"{t.lower}/{t.n}", fmt(t.p_value, 3), fmt(t.holm_p, 3)]
        rows.append([c.a, c.b, c.metric, t.n, *numbers, c.verdict])
    return with_architecture(Rows(header, rows), [c.architecture for c in comparisons], by_architecture)


def comparison_csv_rows(comparisons: Sequence[Comparison], by_architecture: bool = False) -> Rows:
    """``tables/pairwise.csv``: full precision (with ``by_architecture`` an ``architecture`` column first);
    ``sequences``: those each seed's value averages, ``;``-separated."""
    header = ["a", "b", "metric", "seeds", "sequences", "mean_diff", "ci_low", "ci_high", "a_lower",
              "p_value", "method", "holm_p", "verdict"]  # fmt: skip
    rows: list[list[object]] = []
    for c in comparisons:
        t = c.test
        effect = [*map(repr, (t.mean_diff, t.ci_low, t.ci_high)), t.lower, repr(t.p_value), t.method]
        rows.append([c.a, c.b, c.metric, t.n, ";".join(c.sequences), *effect, repr(t.holm_p), c.verdict])
    return with_architecture(Rows(header, rows), [c.architecture for c in comparisons], by_architecture)
