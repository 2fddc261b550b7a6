"""The pairwise comparison of configurations on the APE / RPE RMSEs, paired by seed, Holm-corrected over
the pairs of one metric (``tables/pairwise.csv`` and its section of report.md)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import combinations

import numpy as np

from lossvo.report.configurations import architecture_groups
from lossvo.report.jobs import APE_TRANS, RPE_ROT, RPE_TRANS
from lossvo.report.statistics import ALPHA, PairedTest, can_decide, corrected, paired_test
from lossvo.report.tables import NETWORK, Column, evaluated_sequences, fmt, paired_samples, with_architecture
from lossvo.table_render import Rows

COMPARED = (
    ("APE trans RMSE [m]", APE_TRANS),
    ("RPE trans RMSE [m]", RPE_TRANS),
    ("RPE rot RMSE [rad]", RPE_ROT),
)


@dataclass
class Comparison:
    """A vs B on one metric, paired by seed (``test.holm_p`` over ``comparisons`` pairs), each seed's value
    its mean over ``sequences``."""

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
    """Per-seed values (S,) of A and B on their common seeds, each the mean over the ``sequences`` both
    have on every one of them, and those sequences."""
    x, y = paired_samples(a, b, path, sequences)  # (S, sequences)
    common = np.isfinite(x).all(axis=0) & np.isfinite(y).all(axis=0)
    if not len(x) or not common.any():
        return np.array([]), np.array([]), []
    used = [s for s, kept in zip(sequences, common, strict=True) if kept]
    return x[:, common].mean(axis=1), y[:, common].mean(axis=1), used


def compare(columns: Sequence[Column], by_architecture: bool = False) -> list[Comparison]:
    """Every pair of network columns (of one architecture with ``by_architecture``) on each metric of
    :data:`COMPARED`, Holm over the pairs of one metric."""
    networks = [c for c in columns if c.kind == NETWORK]
    sequences = evaluated_sequences(networks)
    out = []
    for group in architecture_groups(networks, by_architecture).values():
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
    """The section's table."""
    header = ["A", "B", "metric", "seeds", "mean A − B", "A lower", "p", "Holm p",
              f"distinguishable at {ALPHA}"]  # fmt: skip
    rows: list[list[object]] = []
    for c in comparisons:
        t = c.test
        numbers = [fmt(t.mean_diff), f"{t.lower}/{t.n}", fmt(t.p_value, 3), fmt(t.holm_p, 3)]
        rows.append([c.architecture, c.a, c.b, c.metric, t.n, *numbers, c.verdict])
    return with_architecture(header, rows, by_architecture)


def comparison_csv_rows(comparisons: Sequence[Comparison], by_architecture: bool = False) -> Rows:
    """``tables/pairwise.csv`` at full precision."""
    header = ["a", "b", "metric", "seeds", "sequences", "mean_diff", "ci_low", "ci_high", "a_lower",
              "p_value", "method", "holm_p", "verdict"]  # fmt: skip
    rows: list[list[object]] = []
    for c in comparisons:
        t = c.test
        effect = [*map(repr, (t.mean_diff, t.ci_low, t.ci_high)), t.lower, repr(t.p_value), t.method]
        what = [c.architecture, c.a, c.b, c.metric, t.n, ";".join(c.sequences)]
        rows.append([*what, *effect, repr(t.holm_p), c.verdict])
    return with_architecture(header, rows, by_architecture)
