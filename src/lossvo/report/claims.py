"""The study's claims, tested on the numbers: (a) "the chordal loss gives the lowest errors" (on the
sequences outside the training split) and (b) "it converges fastest", each for every chordal
configuration against every other, with paired tests and a verdict by the rule of
:mod:`lossvo.report.statistics` (the last section of report.md and the rows of ``tables/claims.csv``);
where a sweep varies the architecture, within each architecture (:func:`claims_by_architecture`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from lossvo.report import render, statistics
from lossvo.report.comparison import paired_values
from lossvo.report.configurations import SCORE, UNKNOWN_ARCHITECTURE, architecture_groups, loss_class_name
from lossvo.report.convergence import Convergence, epoch_text
from lossvo.report.jobs import APE_TRANS, RPE_ROT, RPE_TRANS, trained_sequences
from lossvo.report.render import Rows, prepend_column
from lossvo.report.statistics import PairedTest
from lossvo.report.tables import NETWORK, Cell, Column, fmt, mean_std_text, samples

CLAIMED_LOSS = "ChordalLoss"
CLAIM_ERRORS = (
    ("RPE trans RMSE [m]", RPE_TRANS),
    ("RPE rot RMSE [rad]", RPE_ROT),
    ("APE trans RMSE [m]", APE_TRANS),
)
CLAIM_A = "the chordal loss gives the lowest errors"
CLAIM_B = "it converges fastest"
EPOCHS = "convergence epoch"


@dataclass
class QuantityTests:
    """The claimed configuration against each other on one quantity (an error metric or the
    convergence epoch): the paired tests and their verdict."""

    quantity: str
    tests: list[PairedTest]
    verdict: str


@dataclass
class Claim:
    """One claim about one claimed configuration: what was paired (``scope``), per configuration the
    measured numbers ``{label: {quantity: Cell over seeds}}``, the tests per quantity, the overall
    verdict and notes. ``untested`` says why there are no tests (then ``verdict`` is empty).
    ``architecture``: the architecture it was tested within (:func:`claims_by_architecture`), else None."""

    statement: str
    configuration: str
    scope: str = ""
    measured: dict[str, dict[str, Cell]] = field(default_factory=dict)
    quantities: list[QuantityTests] = field(default_factory=list)
    verdict: str = ""
    notes: list[str] = field(default_factory=list)
    untested: str | None = None
    architecture: str | None = None


def is_claimed(column: Column) -> bool:
    """Whether a network column is a chordal configuration: every job's ``loss._target_`` class is
    :data:`CLAIMED_LOSS`."""
    return (
        column.kind == NETWORK
        and bool(column.jobs)
        and all(loss_class_name(j) == CLAIMED_LOSS for j in column.jobs)
    )


def training_sequences(columns: Sequence[Column]) -> set[str]:
    """The union of the evaluated sequences the jobs' networks were trained on
    (:func:`lossvo.report.jobs.trained_sequences`)."""
    return {s for c in columns for j in c.jobs for s in trained_sequences(j)}


def restrict(column: Column, sequences: Sequence[str]) -> Column:
    """A copy of a column whose results hold only ``sequences``."""
    results = [{s: r[s] for s in sequences if s in r} for r in column.results]
    return Column(column.label, column.kind, list(column.replicates), results, list(column.jobs))


def seed_means(column: Column, path: Sequence[str], sequences: Sequence[str]) -> Cell:
    """Mean ± std over seeds of each seed's mean of one metric over ``sequences`` (a seed missing one
    sequence is left out)."""
    values = samples(column, path, sequences)  # (seeds, sequences)
    return Cell.of(values.mean(axis=1) if values.shape[1] else np.array([]))


def error_claim(claimed: Column, others: Sequence[Column], heldout: Sequence[str]) -> Claim:
    """Claim (a): the claimed configuration's errors against every other's, paired over (seed, held-out
    sequence), one verdict per metric of :data:`CLAIM_ERRORS`, combined by
    :func:`lossvo.report.statistics.combine`."""
    scope = f"On the sequences outside the training split: {', '.join(heldout)}."
    claim = Claim(CLAIM_A, claimed.label, scope)
    for column in (claimed, *others):
        claim.measured[column.label] = {q: seed_means(column, p, heldout) for q, p in CLAIM_ERRORS}
    a = restrict(claimed, heldout)
    for quantity, path in CLAIM_ERRORS:
        tests = []
        for other in others:
            x, y, _ = paired_values(a, restrict(other, heldout), path)
            tests.append(statistics.paired_test(other.label, x, y))
        claim.quantities.append(QuantityTests(quantity, tests, statistics.verdict(tests)))
    claim.verdict = statistics.combine([q.verdict for q in claim.quantities])
    claim.notes.append(
        "The sequences of one seed share one trained network, so the (seed, sequence) pairs are not fully "
        "independent: read p as indicative."
    )
    return claim


def epoch_test(claimed: Convergence, other: Convergence) -> PairedTest:
    """The claimed configuration's convergence epochs against ``other``'s, paired by seed (seeds where
    either has no epoch are left out)."""
    pairs = [(claimed.epoch_of(r), other.epoch_of(r)) for r in claimed.replicates]
    kept = [(x, y) for x, y in pairs if x is not None and y is not None]
    x, y = (np.array([p[i] for p in kept], dtype=np.float64) for i in (0, 1))
    return statistics.paired_test(other.label, x, y)


def convergence_claim(claimed: Convergence, others: Sequence[Convergence]) -> Claim:
    """Claim (b): the claimed configuration's convergence epochs against every other's, paired by seed."""
    claim = Claim(CLAIM_B, claimed.label, "Paired by seed, on the epochs of *Convergence*.")
    for c in (claimed, *others):
        claim.measured[c.label] = {EPOCHS: c.cell()}
    tests = [epoch_test(claimed, other) for other in others]
    claim.quantities.append(QuantityTests(EPOCHS, tests, statistics.verdict(tests)))
    claim.verdict = claim.quantities[0].verdict
    smallest = sorted({(t.n, statistics.smallest_p(t.n)) for t in tests})
    claim.notes += [
        f"With n = {n} paired seeds the smallest two-sided p an exact Wilcoxon test can give is {fmt(p, 3)}"
        + (f", so p < {statistics.ALPHA} cannot be reached." if p >= statistics.ALPHA else ".")
        for n, p in smallest
    ]
    metrics = {m for c in (claimed, *others) for m in c.metrics}
    if metrics != {SCORE}:
        claim.notes.append(
            f"Not every job logged `{SCORE}`: epochs are measured on {', '.join(sorted(metrics))}, curves "
            "that are not on one scale across losses."
        )
    return claim


def study_claims(
    columns: Sequence[Column], items: Sequence[Convergence], sequences: Sequence[str]
) -> list[Claim]:
    """Claims (a) and (b) for every chordal configuration against all non-chordal ones (an untested
    claim says why: no chordal configuration, nothing to compare with, no held-out sequence)."""
    networks = [c for c in columns if c.kind == NETWORK]
    claimed = [c for c in networks if is_claimed(c)]
    others = [c for c in networks if not is_claimed(c)]
    if not claimed:
        reason = f"the sweep has no chordal configuration (no job with loss._target_ {CLAIMED_LOSS})"
        return [Claim(s, "", untested=reason) for s in (CLAIM_A, CLAIM_B)]
    train = training_sequences(networks)
    heldout = [s for s in sequences if s not in train]
    by_label = {c.label: c for c in items}
    out = []
    for column in claimed:
        if not others:
            reason = "no other configuration with results to compare with"
            out += [Claim(s, column.label, untested=reason) for s in (CLAIM_A, CLAIM_B)]
            continue
        if heldout:
            a = error_claim(column, others, heldout)
        else:
            a = Claim(CLAIM_A, column.label, untested="no evaluated sequence is outside the training split")
        out += [a, convergence_claim(by_label[column.label], [by_label[o.label] for o in others])]
    return out


def claims_by_architecture(
    columns: Sequence[Column], items: Sequence[Convergence], sequences: Sequence[str]
) -> list[Claim]:
    """:func:`study_claims` within each architecture (its chordal configurations against its other
    configurations), architecture by architecture, each claim naming its architecture."""
    out = []
    for architecture, group in architecture_groups(columns).items():
        labels = {c.label for c in group}
        for claim in study_claims(group, [i for i in items if i.label in labels], sequences):
            claim.architecture = architecture
            out.append(claim)
    return out


# --------------------------------------------------------------------------------------------------
# Text and rows
# --------------------------------------------------------------------------------------------------

CLAIMS_RULE = (
    f"Verdict rule (`lossvo.report.statistics.verdict`): the chordal configuration (`loss._target_` class "
    f"`{CLAIMED_LOSS}`) is paired with every other configuration and each pair is tested with a two-sided "
    f"Wilcoxon signed-rank test (`scipy.stats.wilcoxon`). **{statistics.SUPPORTED}**: the chordal mean is "
    f"lower than every other configuration's and every p < {statistics.ALPHA}; "
    f"**{statistics.CONTRADICTED}**: some other configuration's mean is lower with p < {statistics.ALPHA}; "
    f"otherwise **{statistics.NOT_DISTINGUISHABLE}**. Claim (a) is tested per error metric, paired over "
    f"(seed, sequence) on the sequences outside the training split (`data.train`), and the metrics "
    f"combine as: {statistics.CONTRADICTED} if any metric is, {statistics.SUPPORTED} if all are, otherwise "
    f"{statistics.NOT_DISTINGUISHABLE}. Claim (b) pairs the convergence epochs (*Convergence*) by seed."
)


def _measured_rows(claim: Claim) -> Rows:
    quantities = list(next(iter(claim.measured.values())))
    fmt_cell = epoch_text if quantities == [EPOCHS] else mean_std_text
    rows: list[list[object]] = [
        [label, *(fmt_cell(cells[q]) for q in quantities)] for label, cells in claim.measured.items()
    ]
    return Rows(["configuration", *quantities], rows)


def _epochs_number(x: float) -> str:
    return f"{x:.2f}" if math.isfinite(x) else "n/a"


def _tests_rows(claim: Claim) -> Rows:
    header = ["quantity", f"{claim.configuration} vs", "pairs n", f"mean {claim.configuration}", "mean other",
              "p (Wilcoxon)", "smallest p at this n", "verdict on the quantity"]  # fmt: skip
    rows: list[list[object]] = []
    for q in claim.quantities:
        number = _epochs_number if q.quantity == EPOCHS else fmt
        for t in q.tests:
            rows.append([q.quantity, t.versus, t.n, number(t.mean), number(t.versus_mean), fmt(t.p_value, 3),
                         fmt(statistics.smallest_p(t.n), 3), q.verdict])  # fmt: skip
    return Rows(header, rows)


def claim_markdown(claim: Claim, letter: str, level: str = "###") -> str:
    """One claim under a heading of ``level``: measured numbers (mean ± std over seeds), the paired tests
    and the verdict."""
    head = f'{level} ({letter}) "{claim.statement}"'
    head += f" ({claim.configuration})" if claim.configuration else ""
    if claim.untested:
        return f"{head}\n\nCannot be tested: {claim.untested}."
    what = "each seed's mean over those sequences" if claim.statement == CLAIM_A else "epochs"
    lines = [head, "", claim.scope, "", f"Measured ({what}; mean ± sample std over seeds):", ""]
    lines += [
        render.markdown(_measured_rows(claim)),
        "",
        "Paired tests:",
        "",
        render.markdown(_tests_rows(claim)),
    ]
    lines += [f"\n*Note:* {n}" for n in claim.notes]
    lines += ["", f"**Verdict: {claim.verdict}.**"]
    return "\n".join(lines)


BY_ARCHITECTURE_TEXT = (
    "This sweep varies the architecture: each claim is tested within each architecture, its chordal "
    "configuration against that architecture's other configurations, with a verdict per architecture."
)


def claims_markdown(items: Sequence[Claim], by_architecture: bool = False) -> str:
    """The rule and every claim; with ``by_architecture`` a subsection per architecture."""
    letters = {CLAIM_A: "a", CLAIM_B: "b"}
    if not by_architecture:
        return "\n\n".join([CLAIMS_RULE, *(claim_markdown(c, letters[c.statement]) for c in items)])
    parts = [CLAIMS_RULE, BY_ARCHITECTURE_TEXT]
    for architecture in dict.fromkeys(c.architecture or UNKNOWN_ARCHITECTURE for c in items):
        parts.append(f"### Architecture `{architecture}`")
        parts += [
            claim_markdown(c, letters[c.statement], "####")
            for c in items
            if (c.architecture or UNKNOWN_ARCHITECTURE) == architecture
        ]
    return "\n\n".join(parts)


CLAIMS_HEADER = [
    "claim",
    "configuration",
    "versus",
    "quantity",
    "n",
    "mean",
    "versus_mean",
    "p_value",
    "smallest_p",
    "verdict",
    "note",
]


def _test_numbers(t: PairedTest) -> list[object]:
    """A paired test's ``n, mean, versus_mean, p_value, smallest_p`` cells, full precision."""
    return [t.n, repr(t.mean), repr(t.versus_mean), repr(t.p_value), repr(statistics.smallest_p(t.n))]


def claims_csv_rows(items: Sequence[Claim], by_architecture: bool = False) -> Rows:
    """``tables/claims.csv``: one row per paired test (``verdict``: that quantity's), then one ``all`` row
    per claim with its verdict; an untested claim is one row with verdict ``cannot be tested`` and the
    reason in ``note``; with ``by_architecture`` the claim's architecture first."""
    rows: list[list[object]] = []
    architectures: list[str] = []
    for c in items:
        start = len(rows)
        if c.untested:
            rows.append([c.statement, c.configuration, *[""] * 7, "cannot be tested", c.untested])
        else:
            for q in c.quantities:
                for t in q.tests:
                    rows.append(
                        [c.statement, c.configuration, t.versus, q.quantity, *_test_numbers(t), q.verdict, ""]
                    )
            rows.append([c.statement, c.configuration, "all", "all", *[""] * 5, c.verdict, " ".join(c.notes)])
        architectures += [c.architecture or UNKNOWN_ARCHITECTURE] * (len(rows) - start)
    table = Rows(CLAIMS_HEADER, rows)
    return prepend_column(table, "architecture", architectures) if by_architecture else table


def claims_csv(items: Sequence[Claim], by_architecture: bool = False) -> str:
    """:func:`claims_csv_rows` as CSV text."""
    return render.csv_text(claims_csv_rows(items, by_architecture))
