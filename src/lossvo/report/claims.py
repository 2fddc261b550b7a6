"""The study's claims about a loss class, tested on the numbers with seeds as the unit: (a) "it gives the
lowest errors" on the held-out sequences and (b) "it converges fastest" (the last section of report.md and
``tables/claims.csv``). The rule: docs/report.md (*Seeds are the unit*)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from lossvo import table_render
from lossvo.report import statistics
from lossvo.report.configurations import SCORE, architecture_groups, loss_class_name
from lossvo.report.convergence import Convergence, epoch_text
from lossvo.report.jobs import APE_TRANS, RPE_ROT, RPE_TRANS, trained_sequences
from lossvo.report.statistics import CANNOT_DECIDE, PairedTest
from lossvo.report.tables import (
    NETWORK,
    UNKNOWN_ARCHITECTURE,
    Cell,
    Column,
    evaluated_sequences,
    fmt,
    mean_std_text,
    paired_samples,
    seed_scores,
    with_architecture,
)
from lossvo.table_render import Rows

CLAIMED_LOSS = "ChordalLoss"
"""The default ``loss._target_`` class the claims are about (``--claimed-loss``)."""
CLAIM_ERRORS = (
    ("RPE trans RMSE [m]", RPE_TRANS),
    ("RPE rot RMSE [rad]", RPE_ROT),
    ("APE trans RMSE [m]", APE_TRANS),
)
CLAIM_A = "the {loss} loss gives the lowest errors"
CLAIM_B = "it converges fastest"
EPOCHS = "convergence epoch"
SECONDARY = "secondary: (seed, sequence) cells share a network; indicative only"


@dataclass
class QuantityTests:
    """One quantity's Holm family of paired tests over seeds, and the :data:`SECONDARY` tests over cells."""

    quantity: str
    tests: list[PairedTest]
    verdict: str
    secondary: list[PairedTest] = field(default_factory=list)
    decisions: list[str] = field(default_factory=list)


@dataclass
class Claim:
    """One claim about one configuration; ``measured``: ``{label: {quantity: Cell over seeds}}``."""

    statement: str
    configuration: str
    scope: str = ""
    margin: float = statistics.MARGIN
    sequences: list[str] = field(default_factory=list)
    measured: dict[str, dict[str, Cell]] = field(default_factory=dict)
    quantities: list[QuantityTests] = field(default_factory=list)
    verdict: str = ""
    notes: list[str] = field(default_factory=list)
    untested: str | None = None
    architecture: str | None = None
    undecidable: list[str] = field(default_factory=list)
    claimed_loss: str = CLAIMED_LOSS

    @property
    def letter(self) -> str:
        """``a`` (the errors) or ``b`` (convergence)."""
        return "b" if self.statement == CLAIM_B else "a"


def loss_word(claimed_loss: str) -> str:
    """How the report's text names a loss class: ``ChordalLoss`` -> ``chordal``."""
    return claimed_loss.removesuffix("Loss").lower()


def is_claimed(column: Column, claimed_loss: str = CLAIMED_LOSS) -> bool:
    """Whether every job of a network column has the ``loss._target_`` class ``claimed_loss``."""
    return (
        column.kind == NETWORK
        and bool(column.jobs)
        and all(loss_class_name(j) == claimed_loss for j in column.jobs)
    )


def training_sequences(columns: Sequence[Column]) -> set[str]:
    """The evaluated sequences some job of ``columns`` was trained on."""
    return {s for c in columns for j in c.jobs for s in trained_sequences(j)}


def heldout_sequences(columns: Sequence[Column], sequences: Sequence[str]) -> list[str]:
    """The ``sequences`` that some job of ``columns`` evaluated and none of them trained on, in order."""
    train = training_sequences(columns)
    return [s for s in evaluated_sequences(columns, sequences) if s not in train]


def seed_test(
    versus: str, claimed: Mapping[str, float], other: Mapping[str, float], margin: float = statistics.MARGIN
) -> PairedTest:
    """The paired test of per-seed values ``{seed: value}`` against ``versus``'s, on the seeds both have."""
    seeds = [r for r in claimed if r in other]
    x, y = (np.array([v[r] for r in seeds], dtype=np.float64) for v in (claimed, other))
    return statistics.paired_test(versus, x, y, margin)


def cells_test(claimed: Column, other: Column, path: Sequence[str], sequences: Sequence[str]) -> PairedTest:
    """The :data:`SECONDARY` test: paired over the (seed, sequence) cells of ``sequences`` both have."""
    x, y = paired_samples(claimed, other, path, sequences)
    both = np.isfinite(x) & np.isfinite(y)
    return statistics.cells_test(other.label, x[both], y[both])


def quantity_tests(
    quantity: str, tests: Sequence[PairedTest], secondary: Sequence[PairedTest] = ()
) -> QuantityTests:
    """One quantity's tests as one Holm family, each with its decision, and their verdict."""
    family = statistics.corrected(tests)
    decisions = [statistics.decide(t) for t in family]
    return QuantityTests(quantity, family, statistics.verdict(tests), list(secondary), decisions)


def undecidable(n: int, comparisons: int) -> str | None:
    """Why n paired seeds cannot decide a family of ``comparisons`` tests (None where they can or n = 0)."""
    if n == 0 or statistics.can_decide(n, comparisons):
        return None
    alpha, needed = statistics.ALPHA, statistics.min_seeds(comparisons)
    seeds = "seed" if n == 1 else "seeds"
    text = (
        f"{n} {seeds} cannot decide: the smallest p an exact test can give with {n} paired {seeds} is "
        f"{fmt(statistics.smallest_p(n), 3)}"
    )
    if comparisons == 1:
        return f"{text} ({needed} seeds are needed for p < {alpha})."
    corrected = fmt(statistics.smallest_holm_p(n, comparisons), 3)
    return (
        f"{text}, {corrected} after Holm's correction over {comparisons} comparisons ({needed} seeds are "
        f"needed for a corrected p < {alpha})."
    )


def decided(claim: Claim) -> Claim:
    """``claim`` with its verdict, its quantities' combined, and :func:`undecidable` for every n among its
    undecided tests, each sentence once."""
    claim.verdict = statistics.combine([q.verdict for q in claim.quantities])
    undecided = (undecidable(t.n, len(q.tests)) for q, t, d in _comparisons(claim) if d == CANNOT_DECIDE)
    claim.undecidable = list(dict.fromkeys(x for x in undecided if x))
    return claim


def error_claim(
    claimed: Column,
    others: Sequence[Column],
    heldout: Sequence[str],
    margin: float = statistics.MARGIN,
    claimed_loss: str = CLAIMED_LOSS,
) -> Claim:
    """Claim (a) on each metric of :data:`CLAIM_ERRORS`, each seed's mean over the ``heldout`` sequences."""
    scope = f"On the sequences outside the training split: {', '.join(heldout)}."
    claim = Claim(CLAIM_A.format(loss=loss_word(claimed_loss)), claimed.label, scope, margin, list(heldout))
    columns = (claimed, *others)
    for quantity, path in CLAIM_ERRORS:
        ours, *theirs = scores = [seed_scores(c, path, heldout) for c in columns]
        for column, values in zip(columns, scores, strict=True):
            claim.measured.setdefault(column.label, {})[quantity] = Cell.of(list(values.values()))
        tests = [seed_test(o.label, ours, s, margin) for o, s in zip(others, theirs, strict=True)]
        cells = [cells_test(claimed, other, path, heldout) for other in others]
        claim.quantities.append(quantity_tests(quantity, tests, cells))
    return decided(claim)


def convergence_claim(
    claimed: Convergence, others: Sequence[Convergence], margin: float = statistics.MARGIN
) -> Claim:
    """Claim (b): the claimed configuration's convergence epochs against every other's, paired by seed."""
    claim = Claim(CLAIM_B, claimed.label, "Paired by seed, on the epochs of *Convergence*.", margin)
    for c in (claimed, *others):
        claim.measured[c.label] = {EPOCHS: c.cell()}
    tests = [seed_test(o.label, claimed.seed_epochs, o.seed_epochs, margin) for o in others]
    claim.quantities.append(quantity_tests(EPOCHS, tests))
    metrics = {m for c in (claimed, *others) for m in c.metrics}
    if metrics != {SCORE}:
        claim.notes.append(
            f"Not every job logged `{SCORE}`: epochs are measured on {', '.join(sorted(metrics))}, curves "
            "that are not on one scale across losses."
        )
    return decided(claim)


def study_claims(
    columns: Sequence[Column],
    items: Sequence[Convergence],
    sequences: Sequence[str],
    margin: float = statistics.MARGIN,
    claimed_loss: str = CLAIMED_LOSS,
) -> list[Claim]:
    """Claims (a) and (b) for every configuration of ``claimed_loss`` against all others, (a) on the
    :func:`heldout_sequences` of ``sequences``; an untested claim says why."""
    networks = [c for c in columns if c.kind == NETWORK]
    claimed = [c for c in networks if is_claimed(c, claimed_loss)]
    others = [c for c in networks if not is_claimed(c, claimed_loss)]
    word = loss_word(claimed_loss)
    statements = (CLAIM_A.format(loss=word), CLAIM_B)
    if not claimed:
        reason = f"the sweep has no {word} configuration (no job with loss._target_ {claimed_loss})"
        return [Claim(s, "", untested=reason, claimed_loss=claimed_loss) for s in statements]
    heldout = heldout_sequences(networks, sequences)
    by_label = {c.label: c for c in items}
    out = []
    for column in claimed:
        if not others:
            reason = "no other configuration with results to compare with"
            out += [Claim(s, column.label, untested=reason) for s in statements]
            continue
        if heldout:
            a = error_claim(column, others, heldout, margin, claimed_loss)
        else:
            why = "no evaluated sequence is outside the training split"
            a = Claim(statements[0], column.label, untested=why)
        out += [a, convergence_claim(by_label[column.label], [by_label[o.label] for o in others], margin)]
    for claim in out:
        claim.claimed_loss = claimed_loss
    return out


def claims_by_architecture(
    columns: Sequence[Column],
    items: Sequence[Convergence],
    sequences: Sequence[str],
    margin: float = statistics.MARGIN,
    claimed_loss: str = CLAIMED_LOSS,
) -> list[Claim]:
    """:func:`study_claims` within each architecture (on the sequences it evaluated)."""
    out = []
    for architecture, group in architecture_groups(columns).items():
        labels = {c.label for c in group}
        kept = [i for i in items if i.label in labels]
        for claim in study_claims(group, kept, sequences, margin, claimed_loss):
            claim.architecture = architecture
            out.append(claim)
    return out


def claims_rule(margin: float = statistics.MARGIN, claimed_loss: str = CLAIMED_LOSS) -> str:
    """How a claim is decided, in the report's words."""
    alpha, delta, level = statistics.ALPHA, f"{100 * margin:g} %", 1 - 2 * statistics.ALPHA
    word = loss_word(claimed_loss)
    parts = [
        "Rule (`lossvo.report.statistics`): seeds are the unit, since the sequences of one seed share one",
        "trained network. A seed's value is its mean over the evaluated sequences outside the training",
        "split (`data.splits.train`) for claim (a), its convergence epoch (*Convergence*) for claim (b); the",
        f"{word} configuration (`loss._target_` class `{claimed_loss}`) is paired by seed with every other",
        "configuration, and each pair is judged on its n per-seed relative differences",
        f"r = ({word} − other) / other. **{statistics.EQUIVALENT} within ±{delta}**: the {100 * level:g} %",
        f"t-interval of the mean of r (`scipy.stats.ttest_1samp(r).confidence_interval({level:g})`) lies",
        f"inside ±{delta}, i.e. both one-sided t-tests of TOST reject at {alpha} (*TOST p*; no correction:",
        "equivalence to every other configuration is an intersection-union test). Otherwise the per-seed",
        f"differences d = {word} − other are tested with the two-sided exact Wilcoxon signed-rank test",
        '(`scipy.stats.wilcoxon`, `method="exact"`; where d has ties or zeros, the exact sign-flip test',
        "of the mean, `scipy.stats.permutation_test`), and the p-values of one claim on one quantity",
        f"(the {word} configuration against each of the m others) are one family, corrected by Holm's",
        f"step-down (*Holm p*): Holm p < {alpha} with the {word} mean lower: **{statistics.SUPPORTED}**,",
        f"higher: **{statistics.REFUTED}**; otherwise **{statistics.CANNOT_DECIDE}**,",
        "with the seeds needed for either outcome: *seeds to detect* is",
        "⌈((z_{1−α/(2m)} + z_{0.8}) · sd_d / |mean_d|)²⌉, the seeds at",
        "which a paired test at α/m would detect the observed difference with 80 % power (never fewer than",
        "the seeds that can decide: no exact test on n seeds gives p below 2/2^n, so 6 seeds against one",
        "other configuration, 7 against two or three); *seeds for equivalence* is",
        f"⌈((z_{{1−α}} + z_{{0.8}}) · sd_r / ({delta} − |mean_r|))²⌉, the seeds at which TOST would show",
        f"equivalence if the observed difference were the true one (∞ where it is outside ±{delta}). A",
        "claim's comparisons, and then claim (a)'s metrics, combine as:",
        f"{statistics.REFUTED} if any is; {statistics.SUPPORTED} or {statistics.EQUIVALENT} if all are;",
        f"*{statistics.PARTLY}* where each is one of those; otherwise {statistics.CANNOT_DECIDE}. The",
        "95 % CI column is the t-interval of the mean difference in the quantity's unit. Claim (a)'s",
        "Wilcoxon test over (seed, sequence) cells is secondary and never decides:",
        f"{SECONDARY.removeprefix('secondary: ')}.",
    ]
    return " ".join(parts)


def _cell_text(quantity: str, cell: Cell) -> str:
    return epoch_text(cell) if quantity == EPOCHS else mean_std_text(cell)


def _measured_rows(claim: Claim) -> Rows:
    quantities = list(next(iter(claim.measured.values())))
    rows: list[list[object]] = [
        [label, *(_cell_text(q, cells[q]) for q in quantities)] for label, cells in claim.measured.items()
    ]
    return Rows(["configuration", *quantities], rows)


def relative_interval_text(t: PairedTest) -> str:
    """A test's relative difference with its 90 % interval: ``-10.2 % [-11.4, -9.0]``."""
    text = f"{100 * t.rel_mean:+.1f} %" if math.isfinite(t.rel_mean) else "n/a"
    if t.n < 2 or not math.isfinite(t.rel_low):
        return text
    return f"{text} [{100 * t.rel_low:+.1f}, {100 * t.rel_high:+.1f}]"


def seeds_needed_text(n: float, infinite: str = "no effect observed", missing: str = "n/a") -> str:
    """A seeds-needed count as text: ``infinite`` for inf, ``missing`` for NaN."""
    if math.isinf(n):
        return infinite
    return str(int(n)) if math.isfinite(n) else missing


def _comparisons(claim: Claim) -> Iterator[tuple[QuantityTests, PairedTest, str]]:
    for q in claim.quantities:
        yield from ((q, t, decision) for t, decision in zip(q.tests, q.decisions, strict=True))


def _needed(t: PairedTest) -> list[str]:
    return [seeds_needed_text(t.seeds_needed), seeds_needed_text(t.seeds_equivalence, "outside the margin")]


def _tests_rows(claim: Claim) -> Rows:
    header = ["quantity", "versus", "n seeds", f"mean difference ({claim.configuration} − other)",
              "95 % CI", "relative, 90 % CI", "p", "Holm p", "TOST p", "seeds to detect",
              "seeds for equivalence", "verdict"]  # fmt: skip
    rows: list[list[object]] = []
    for q, t, decision in _comparisons(claim):
        number = (lambda x: f"{x:.2f}" if math.isfinite(x) else "n/a") if q.quantity == EPOCHS else fmt
        ci = f"[{number(t.ci_low)}, {number(t.ci_high)}]" if t.n > 1 else "n/a"
        ps = [fmt(x, 3) for x in (t.p_value, t.holm_p, t.tost_p)]
        numbers = [number(t.mean_diff), ci, relative_interval_text(t), *ps, *_needed(t)]
        rows.append([q.quantity, t.versus, t.n, *numbers, statistics.verdict_text(decision, claim.margin)])
    return Rows(header, rows)


def _secondary_rows(claim: Claim) -> Rows:
    header = ["quantity", "versus", "cells", "mean difference", "p (Wilcoxon over cells)"]
    rows: list[list[object]] = [
        [q.quantity, t.versus, t.n, fmt(t.mean_diff), fmt(t.p_value, 3)]
        for q in claim.quantities
        for t in q.secondary
    ]
    return Rows(header, rows)


def claim_markdown(claim: Claim, level: str = "###") -> str:
    """One claim under a heading of ``level``: measured numbers, tests, verdict."""
    head = f'{level} ({claim.letter}) "{claim.statement}"'
    head += f" ({claim.configuration})" if claim.configuration else ""
    if claim.untested:
        return f"{head}\n\nCannot be tested: {claim.untested}."
    what = "each seed's mean over those sequences" if claim.letter == "a" else "epochs"
    measured = f"Measured ({what}; mean ± sample std over seeds):"
    blocks = [head, claim.scope, measured, table_render.markdown(_measured_rows(claim))]
    blocks += ["Paired by seed:", table_render.markdown(_tests_rows(claim))]
    secondary = _secondary_rows(claim)
    if secondary.rows:
        title = f"{SECONDARY[0].upper()}{SECONDARY[1:]} (never decides the verdict):"
        blocks += [title, table_render.markdown(secondary)]
    blocks += [f"*Note:* {n}" for n in claim.notes]
    verdict = statistics.verdict_text(claim.verdict, claim.margin)
    blocks.append(" ".join([f"**Verdict: {verdict}.**", *claim.undecidable]))
    return "\n\n".join(blocks)


BY_ARCHITECTURE_TEXT = (
    "This sweep varies the architecture: each claim is tested within each architecture (and training "
    "data, where the sweep varies `data`), its {loss} configuration against that architecture's other "
    "configurations on the sequences they evaluated, with a verdict per architecture."
)


def answer_rows(items: Sequence[Claim], claimed_loss: str = CLAIMED_LOSS) -> Rows:
    """The study's answer in one table, a row per comparison of every claim."""
    rows: list[list[object]] = []
    for c in items:
        for q, t, decision in _comparisons(c):
            ours, theirs = (
                _cell_text(q.quantity, c.measured[x][q.quantity]) for x in (c.configuration, t.versus)
            )
            needed = " / ".join(_needed(t)) if decision == statistics.CANNOT_DECIDE else ""
            verdict = statistics.verdict_text(decision, c.margin)
            row = [q.quantity, ours, t.versus, theirs, relative_interval_text(t), t.n, verdict, needed]
            rows.append([c.architecture or "", *row])
    header = ["architecture", "quantity", loss_word(claimed_loss), "versus", "other", "relative, 90 % CI",
              "n seeds", "verdict", "seeds to detect / for equivalence"]  # fmt: skip
    return Rows(header, rows)


def claims_markdown(items: Sequence[Claim], by_architecture: bool = False) -> str:
    """The rule and every claim; with ``by_architecture`` a subsection per architecture (``items`` grouped by
    architecture, as :func:`claims_by_architecture` gives them)."""
    first = items[0] if items else Claim("", "")
    answer = answer_rows(items, first.claimed_loss)
    head = [claims_rule(first.margin, first.claimed_loss)]
    if answer.rows:
        head.append(f"The answer, comparison by comparison:\n\n{table_render.markdown(answer)}")
    if not by_architecture:
        return "\n\n".join([*head, *(claim_markdown(c) for c in items)])
    parts = [*head, BY_ARCHITECTURE_TEXT.format(loss=loss_word(first.claimed_loss))]
    for architecture, claims in itertools.groupby(items, lambda c: c.architecture or UNKNOWN_ARCHITECTURE):
        parts += [f"### Architecture `{architecture}`", *(claim_markdown(c, "####") for c in claims)]
    return "\n\n".join(parts)


CLAIMS_HEADER = ["claim", "configuration", "versus", "quantity", "n_seeds", "mean", "versus_mean",
                 "mean_difference", "relative", "ci_low", "ci_high", "relative_ci_low",
                 "relative_ci_high", "relative_mean", "relative_low_90", "relative_high_90", "p_value",
                 "p_method", "holm_p", "smallest_p", "seeds_needed", "tost_p", "margin",
                 "seeds_for_equivalence", "secondary_cells", "secondary_p", "verdict", "note"]  # fmt: skip
"""``tables/claims.csv``'s columns (docs/report.md)."""


def _test_numbers(t: PairedTest, cells: PairedTest | None) -> list[object]:
    effect = (t.mean, t.versus_mean, t.mean_diff, t.relative, t.ci_low, t.ci_high, *t.relative_ci)
    p = (t.rel_mean, t.rel_low, t.rel_high, t.p_value)
    needed = [seeds_needed_text(n, "inf", "") for n in (t.seeds_needed, t.seeds_equivalence)]
    secondary = [cells.n, repr(cells.p_value)] if cells else ["", ""]
    holm = (t.method, repr(t.holm_p), repr(statistics.smallest_p(t.n)), needed[0])
    return [t.n, *map(repr, (*effect, *p)), *holm, repr(t.tost_p), repr(t.margin), needed[1], *secondary]


def claims_csv_rows(items: Sequence[Claim], by_architecture: bool = False) -> Rows:
    """``tables/claims.csv``: a row per paired test, then an ``all`` row per claim."""
    rows: list[list[object]] = []
    blank = [""] * (len(CLAIMS_HEADER) - 4)
    for c in items:
        claim = [c.architecture, c.statement, c.configuration]
        if c.untested:
            rows.append([*claim, *blank, "cannot be tested", c.untested])
            continue
        for q, t, decision in _comparisons(c):
            numbers = _test_numbers(t, next((s for s in q.secondary if s.versus == t.versus), None))
            rows.append([*claim, t.versus, q.quantity, *numbers, decision, ""])
        rows.append([*claim, "all", "all", *blank[2:], c.verdict, " ".join([*c.undecidable, *c.notes])])
    return with_architecture(CLAIMS_HEADER, rows, by_architecture)
