"""Where a sweep varies the architecture, does the loss ranking agree between architectures? Each
architecture's ranking of its treatments on each quantity of claim (a), and an architecture x loss
interaction test per pair (:func:`lossvo.report.statistics.interaction_test`): the *Architectures* section,
``tables/rankings.csv`` and ``tables/interaction.csv``. See docs/report.md.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path

import numpy as np

from lossvo import table_render
from lossvo.report import statistics
from lossvo.report.across_datasets import Evaluation
from lossvo.report.claims import CLAIM_ERRORS, heldout_sequences
from lossvo.report.configurations import architecture_groups, treatments
from lossvo.report.statistics import InteractionTest
from lossvo.report.tables import Cell, Column, fmt, mean_std_text, seed_scores
from lossvo.table_render import Rows

UNTESTED = "cannot be tested"


@dataclass
class Ranking:
    """One architecture's treatments on one quantity with their cell over seeds, lowest mean first."""

    quantity: str
    architecture: str
    entries: list[tuple[str, Cell]]

    def order(self, among: Sequence[str]) -> list[str]:
        """The treatments of ``among`` in this ranking's order."""
        return [t for t, _ in self.entries if t in among]


@dataclass
class Interaction:
    """The interaction test of two architectures on one quantity (None where ``untested`` says why)."""

    quantity: str
    architectures: tuple[str, str]
    treatments: list[str]
    seeds: list[str]
    same_order: bool
    test: InteractionTest | None
    verdict: str
    untested: str | None = None
    sequences: list[str] = field(default_factory=list)


@dataclass
class Agreement:
    """The section: the held-out ``sequences``, the rankings and the tests; ``untested`` says why none."""

    sequences: list[str] = field(default_factory=list)
    rankings: list[Ranking] = field(default_factory=list)
    interactions: list[Interaction] = field(default_factory=list)
    untested: str | None = None


def rank(quantity: str, architecture: str, scores: dict[str, dict[str, float]]) -> Ranking:
    """``scores`` ({treatment: {seed: score}}) ranked by the mean over seeds, lowest first (none last)."""
    cells = {t: Cell.of(list(v.values())) for t, v in scores.items()}
    order = sorted(cells, key=lambda t: (cells[t].n == 0, cells[t].mean if cells[t].n else 0.0))
    return Ranking(quantity, architecture, [(t, cells[t]) for t in order])


NO_COMMON = (
    "no sequence of one dataset that both evaluated and neither trained on (evaluate one's checkpoints on "
    "the other's data into <sweep>/evaluations/<data>/<job>: python -m lossvo.eval ckpt_path=... data=... "
    "hydra.run.dir=...)"
)


def interaction(
    quantity: str,
    pair: tuple[Ranking, Ranking],
    scores: tuple[dict[str, dict[str, float]], ...],
    keys: Sequence[str],
) -> Interaction:
    """The interaction test of architectures A, B from their rankings and {treatment: {seed: score}}, a
    seed's score its mean over the :func:`keyed` sequences ``keys``."""
    (a, b), (sa, sb) = pair, scores
    names = (a.architecture, b.architecture)
    if not keys:
        return Interaction(quantity, names, [], [], False, None, UNTESTED, NO_COMMON)
    common = [t for t in a.order(list(sa)) if t in sb]
    seeds = [r for r in sa[common[0]] if all(r in s[t] for s in (sa, sb) for t in common)] if common else []
    same, sequences = a.order(common) == b.order(common), [sequence_name(k) for k in keys]
    why = None
    if len(common) < 2:
        why = "fewer than two configurations in both architectures (nothing to rank)"
    elif not seeds:
        why = "no seed with a score in every configuration of both architectures"
    if why is not None:
        return Interaction(quantity, names, common, seeds, same, None, UNTESTED, why, sequences)
    d = np.array([[sb[t][r] - sa[t][r] for r in seeds] for t in common])  # (L, S): B - A
    test = statistics.interaction_test(d)
    verdict = statistics.interaction_verdict(test)
    return Interaction(quantity, names, common, seeds, same, test, verdict, sequences=sequences)


KEY_SEPARATOR = "|"
"""Between a dataset's folder and a sequence's name in a :func:`keyed` column's results."""


def _root(path: str | None) -> str:
    return os.path.realpath(path) if path else "?"


def keyed(
    column: Column, sequences: Sequence[str], evaluations: Sequence[Evaluation]
) -> tuple[Column, set[str]]:
    """A copy of a network column with results keyed ``<dataset folder>|<sequence>`` (with its jobs'
    ``evaluations``), and the keys its jobs trained on."""
    results, trained = [], set()
    for job, per_sequence in zip(column.jobs, column.results, strict=True):
        data = job.results.data if job.results is not None else None
        root = _root(data.root if data else None)
        entry = {f"{root}{KEY_SEPARATOR}{s}": per_sequence[s] for s in sequences if s in per_sequence}
        for other in (e.results for e in evaluations if e.job.path == job.path):
            key = _root(other.data.root) + KEY_SEPARATOR
            entry.update({f"{key}{s}": r.scores for s, r in other.sequences.items() if r.scores})
        results.append(entry)
        if data is not None:
            trained |= {f"{_root(data.train_root)}{KEY_SEPARATOR}{s}" for s in data.train}
    copy = Column(column.label, column.kind, list(column.replicates), results, list(column.jobs))
    return copy, trained


def common_held_out(a: Sequence[tuple[Column, set[str]]], b: Sequence[tuple[Column, set[str]]]) -> list[str]:
    """The keys that both groups of :func:`keyed` columns have and none trained on, in ``a``'s order."""
    trained = {k for _, t in (*a, *b) for k in t}
    theirs = {k for c, _ in b for r in c.results for k in r}
    return [k for k in dict.fromkeys(k for c, _ in a for r in c.results for k in r) if k in theirs - trained]


def sequence_name(key: str) -> str:
    """A key as the report names it: ``07 (synthetic)``."""
    root, _, name = key.rpartition(KEY_SEPARATOR)
    return f"{name} ({Path(root).name})"


def architecture_agreement(
    networks: Sequence[Column], sequences: Sequence[str], evaluations: Sequence[Evaluation] = ()
) -> Agreement:
    """Rankings per architecture and interaction tests per pair on each quantity of claim (a)."""
    groups = architecture_groups(networks)
    names = treatments(networks)
    heldout = {architecture: heldout_sequences(group, sequences) for architecture, group in groups.items()}
    every = [s for s in sequences if any(s in h for h in heldout.values())]
    if not every:
        return Agreement(untested="no evaluated sequence is outside the training split")
    out = Agreement(every)
    keyed_groups = {a: [keyed(c, sequences, evaluations) for c in g] for a, g in groups.items()}
    pairs = {(x, y): common_held_out(keyed_groups[x], keyed_groups[y]) for x, y in combinations(groups, 2)}
    for quantity, path in CLAIM_ERRORS:
        scores = {
            architecture: {names[c.label]: seed_scores(c, path, heldout[architecture]) for c in group}
            for architecture, group in groups.items()
        }
        rankings = {architecture: rank(quantity, architecture, s) for architecture, s in scores.items()}
        out.rankings += rankings.values()
        for (x, y), common in pairs.items():
            pair_scores = tuple(
                {names[c.label]: seed_scores(c, path, common) for c, _ in keyed_groups[a]} for a in (x, y)
            )
            out.interactions.append(interaction(quantity, (rankings[x], rankings[y]), pair_scores, common))
    return out


AGREEMENT_TEXT = (
    "The sweep varies the architecture. A seed's score is its mean over the sequences its architecture "
    "evaluated outside its training split (of {sequences}), as in claim (a); each architecture ranks its "
    "configurations, named without the architecture, by the mean over seeds, lowest first. For each pair "
    "of architectures A, B, on the "
    "configurations both have and the seeds every one of them has, the differences d[l, s] = y[B, l, s] − "
    "y[A, l, s] (configuration l, seed s) are tested for an architecture × loss interaction "
    "(`lossvo.report.statistics.interaction_test`): F is the interaction F of the two-way ANOVA with seeds "
    "as blocks, and p (exact) the fraction of the (L!)^S relabellings of the configurations within each "
    "seed whose F is at least the observed one. Relabelling every seed alike leaves F unchanged, so p cannot "
    "go below (L!)^(1−S): 1/36 ≈ 0.028 with 3 losses × 3 seeds, 0.5 with 2 × 2; where that is not below "
    f"{statistics.ALPHA} the test **{statistics.CANNOT_DECIDE}**. p < {statistics.ALPHA}: "
    f"**{statistics.INTERACTION}**; otherwise **{statistics.NO_INTERACTION}**, which is no evidence that "
    "the rankings agree."
)


def ranking_rows(agreement: Agreement) -> Rows:
    """Per quantity and architecture, the configurations lowest first."""
    rows: list[list[object]] = [
        [r.quantity, r.architecture, " < ".join(f"{t} ({mean_std_text(c)})" for t, c in r.entries) or "none"]
        for r in agreement.rankings
    ]
    return Rows(["quantity", "architecture", "ranking (lowest first; mean ± std over seeds)"], rows)


def _test_cells(i: Interaction) -> list[object]:
    t = i.test
    if t is None:
        return ["n/a"] * 4
    kind = "exact" if t.exact else "random"
    return [fmt(t.statistic, 3), fmt(t.p_value, 3), f"{t.permutations} ({kind})", fmt(t.smallest_p, 3)]


def interaction_rows(agreement: Agreement) -> Rows:
    """Per quantity and pair of architectures: what was tested, the test and the verdict."""
    header = ["quantity", "architectures", "configurations", "seeds", "same order", "F", "p",
              "relabellings", "smallest p at this n", "verdict"]  # fmt: skip
    rows: list[list[object]] = []
    for i in agreement.interactions:
        pair, order = " vs ".join(i.architectures), "yes" if i.same_order else "no"
        rows.append(
            [i.quantity, pair, ", ".join(i.treatments), len(i.seeds), order, *_test_cells(i), i.verdict]
        )
    return Rows(header, rows)


def verdict_line(i: Interaction) -> str:
    """The verdict of one test in one line, with n, F and p (and why it cannot decide where it cannot)."""
    head = f"**{i.quantity}, {' vs '.join(i.architectures)}: {i.verdict}.**"
    if i.test is None:
        return f"{head} {i.untested}."
    t = i.test
    n = (
        f"n = {t.seeds} seeds ({', '.join(i.seeds)}) × {t.losses} configurations ({', '.join(i.treatments)}) "
        f"× 2 architectures, a seed's score its mean over {', '.join(i.sequences)}"
    )
    how = "exact" if t.exact else f"{t.permutations} random"
    test = (
        f"{how} randomisation test of the interaction (the configurations' labels permuted within each "
        f"seed{f', {t.permutations} relabellings' if t.exact else ''}): F = {fmt(t.statistic, 3)}, "
        f"p = {fmt(t.p_value, 3)}"
    )
    if t.p_value < statistics.ALPHA:
        why = f" < {statistics.ALPHA}"
    elif not t.can_decide:
        why = f"; the smallest p it can give at this n is {fmt(t.smallest_p, 3)} ≥ {statistics.ALPHA}"
    else:
        why = f" ≥ {statistics.ALPHA}"
    return f"{head} {n}; {test}{why}."


def agreement_markdown(agreement: Agreement) -> str:
    """The *Architectures* section's body: the rule, the rankings, the tests and a verdict line each."""
    if agreement.untested:
        return f"Cannot be tested: {agreement.untested}."
    lines = [
        AGREEMENT_TEXT.format(sequences=", ".join(agreement.sequences)),
        "",
        table_render.markdown(ranking_rows(agreement)),
        "",
        table_render.markdown(interaction_rows(agreement)),
    ]
    for i in agreement.interactions:
        lines += ["", verdict_line(i)]
    return "\n".join(lines)


def rankings_csv_rows(agreement: Agreement) -> Rows:
    """``tables/rankings.csv``: per quantity, architecture and rank (1 = lowest), full precision."""
    rows: list[list[object]] = [
        [r.quantity, r.architecture, k, t, *c.csv()]
        for r in agreement.rankings
        for k, (t, c) in enumerate(r.entries, start=1)
    ]
    return Rows(["quantity", "architecture", "rank", "configuration", "mean", "std", "n"], rows)


def interaction_csv_rows(agreement: Agreement) -> Rows:
    """``tables/interaction.csv``: per quantity and pair of architectures, full precision."""
    header = ["quantity", "architecture_a", "architecture_b", "configurations", "seeds", "same_order",
              "statistic", "p_value", "permutations", "exact", "smallest_p", "verdict", "note",
              "sequences"]  # fmt: skip
    if agreement.untested:
        return Rows(header, [[*[""] * 11, UNTESTED, agreement.untested, ""]])
    rows: list[list[object]] = []
    for i, t in ((i, i.test) for i in agreement.interactions):
        numbers = (
            [repr(t.statistic), repr(t.p_value), t.permutations, t.exact, repr(t.smallest_p)]
            if t
            else [""] * 5
        )
        what = [i.quantity, *i.architectures, ";".join(i.treatments), ";".join(i.seeds), i.same_order]
        rows.append([*what, *numbers, i.verdict, i.untested or "", ";".join(i.sequences)])
    return Rows(header, rows)
