"""The seed-level statistics of the report against independent computations: p-values against scipy's
exact Wilcoxon test and a brute-force enumeration of the sign flips, Holm's correction by hand, the
t-interval against scipy, the seeds needed by the formula, the verdict on corrected p-values, the
"cannot decide" sentences, and the pairwise comparison paired by seed.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import norm, permutation_test, ttest_1samp, wilcoxon
from scipy.stats import t as scipy_t

from lossvo.evaluation.job_folder import KittiError, PoseErrors, Scores, Statistics
from lossvo.report import statistics
from lossvo.report.claims import seeds_needed_text, undecidable
from lossvo.report.comparison import compare, comparison_csv_rows
from lossvo.report.tables import NETWORK, Column, fmt


def brute_force_sign_flip_p(d: np.ndarray) -> float:
    """The two-sided sign-flip p of the mean: the share of the 2^n sign patterns with |sum| >= |sum(d)|."""
    observed = abs(math.fsum(d))
    hits = sum(
        abs(math.fsum(s * x for s, x in zip(signs, d, strict=True))) >= observed - 1e-12
        for signs in itertools.product((1.0, -1.0), repeat=len(d))
    )
    return hits / 2 ** len(d)


@pytest.mark.parametrize("n", [1, 2, 3, 5, 6, 8, 10, 12])
def test_p_without_ties_is_scipys_exact_wilcoxon(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(5):
        d = rng.normal(0.05, 0.1, n)
        p, method = statistics.seed_p(d)
        assert method == statistics.WILCOXON
        assert p == pytest.approx(wilcoxon(d, alternative="two-sided", method="exact").pvalue, abs=1e-12)


@pytest.mark.parametrize(
    "d",
    [[-1.0, 0.0, -1.0], [-1.0, -1.0, -2.0, 0.0, 1.0, -3.0], [0.2, -0.2, 0.5, 0.5, 0.5, -0.1, 0.0, 0.3, 0.3],
     [-2.0, -1.0, -1.0, -1.0, -2.0, -3.0, -1.0, -1.0, -2.0, -1.0]],
)  # fmt: skip
def test_p_with_ties_or_zeros_is_the_exact_sign_flip_test_of_the_mean(d: list[float]) -> None:
    x = np.array(d)
    p, method = statistics.seed_p(x)
    assert statistics.has_ties(x) and method == statistics.SIGN_FLIP
    assert p == pytest.approx(brute_force_sign_flip_p(x), abs=1e-12)
    scipy_p = permutation_test((x,), np.mean, permutation_type="samples", n_resamples=np.inf).pvalue
    assert p == pytest.approx(min(1.0, scipy_p), abs=1e-12)  # scipy's sign flips of a one-sample statistic


def test_sign_flip_edge_cases_and_random_patterns_above_the_enumeration_limit() -> None:
    assert statistics.seed_p(np.zeros(4)) == (1.0, statistics.SIGN_FLIP)
    assert math.isnan(statistics.seed_p(np.array([]))[0])
    assert statistics.sign_flip_p(np.array([1.0, 1.0, 1.0])) == (0.25, True)  # 2 of 8 patterns
    d = np.array([-1.0, -1.0, -2.0, 0.0, 1.0, -3.0, -2.0, -1.0])
    exact, _ = statistics.sign_flip_p(d)
    drawn, is_exact = statistics.sign_flip_p(d, max_enumerated=16)
    assert not is_exact and drawn == pytest.approx(exact, abs=0.01)
    assert statistics.sign_flip_p(d, max_enumerated=16) == (drawn, False)  # fixed seed: reproducible


def test_smallest_p_minimum_seeds_and_whether_n_can_decide() -> None:
    assert [statistics.smallest_p(n) for n in (3, 5, 6, 10)] == [0.25, 0.0625, 0.03125, 2 / 1024]
    assert [statistics.min_seeds(m) for m in (1, 2, 3, 4)] == [6, 7, 7, 8]
    assert statistics.can_decide(6) and not statistics.can_decide(5) and not statistics.can_decide(6, 2)
    assert statistics.smallest_holm_p(6, 2) == 0.0625 and statistics.smallest_holm_p(1, 3) == 1.0


def test_holm_adjusted_p_values_equal_a_hand_computation() -> None:
    # sorted: 0.005 (x4 = 0.02), 0.01 (x3 = 0.03), 0.03 (x2 = 0.06), 0.04 (x1 = 0.04 -> max so far 0.06)
    adjusted = statistics.holm([0.01, 0.04, 0.03, 0.005])
    assert adjusted == pytest.approx([0.03, 0.06, 0.06, 0.02], abs=1e-15)
    assert statistics.holm([0.3, 0.6]) == pytest.approx([0.6, 0.6])  # 2 * 0.3; max(0.6, 0.6)
    assert statistics.holm([0.7, 0.9]) == pytest.approx([1.0, 1.0])  # clipped at 1
    assert statistics.holm([0.02]) == pytest.approx([0.02])
    with_nan = statistics.holm([0.01, math.nan])  # the missing comparison counts in m as p = 1
    assert with_nan[0] == pytest.approx(0.02) and math.isnan(with_nan[1])
    assert statistics.holm([]).shape == (0,)


def test_t_interval_equals_scipys() -> None:
    d = np.array([-0.12, -0.05, -0.2, -0.08, 0.01, -0.11])
    low, high = statistics.t_interval(d)
    expected = scipy_t.interval(0.95, d.size - 1, loc=d.mean(), scale=d.std(ddof=1) / math.sqrt(d.size))
    assert (low, high) == (pytest.approx(expected[0], rel=1e-12), pytest.approx(expected[1], rel=1e-12))
    assert all(math.isnan(x) for x in statistics.t_interval(np.array([1.0])))


def test_seeds_needed_is_the_normal_approximation_but_never_below_the_seeds_that_can_decide() -> None:
    z = norm.ppf(0.975) + norm.ppf(0.8)  # 1.960 + 0.842
    assert statistics.seeds_needed(-0.1, 0.2) == math.ceil((z * 0.2 / 0.1) ** 2) == 32
    z2 = norm.ppf(1 - 0.05 / 4) + norm.ppf(0.8)  # two comparisons: the Bonferroni level 0.025
    assert statistics.seeds_needed(0.1, 0.2, comparisons=2) == math.ceil((z2 * 2) ** 2) == 39
    assert statistics.seeds_needed(-0.1, 0.05) == 6  # (2.8 / 2)^2 = 2 -> the exact test's 6
    assert statistics.seeds_needed(-0.1, 0.0, comparisons=2) == 7
    assert statistics.seeds_needed(0.0, 0.1) == math.inf
    assert math.isnan(statistics.seeds_needed(-0.1, math.nan))
    assert [seeds_needed_text(x) for x in (32.0, math.inf, math.nan)] == ["32", "no effect observed", "n/a"]


def test_paired_test_reports_the_effect_its_interval_and_the_seeds_needed() -> None:
    rng = np.random.default_rng(3)
    other = 1.0 + rng.normal(0, 0.05, 10)
    claimed = other - 0.1 + rng.normal(0, 0.05, 10)
    t = statistics.paired_test("euler", claimed, other)
    d = claimed - other
    assert (t.n, t.lower) == (10, int((d < 0).sum()))
    assert t.mean_diff == pytest.approx(d.mean()) and t.sd_diff == pytest.approx(d.std(ddof=1))
    assert t.relative == pytest.approx(d.mean() / other.mean())
    assert t.relative_ci == pytest.approx((t.ci_low / other.mean(), t.ci_high / other.mean()))
    assert t.holm_p == t.p_value and t.seeds_needed == statistics.seeds_needed(d.mean(), d.std(ddof=1))
    one = statistics.paired_test("euler", np.array([1.0]), np.array([2.0]))
    assert one.p_value == 1.0 and math.isnan(one.sd_diff) and math.isnan(one.seeds_needed)


def test_the_verdict_uses_holm_corrected_p_values() -> None:
    other = 1.0 + np.arange(6.0)
    lower = statistics.paired_test("euler", other - 0.1 * (1 + np.arange(6)), other)  # p = 2/64
    assert lower.p_value == pytest.approx(0.03125)
    assert statistics.verdict([lower]) == statistics.SUPPORTED  # one comparison: 0.031 < 0.05
    family = statistics.corrected([lower, replace(lower, versus="quat")])
    assert [t.holm_p for t in family] == [0.0625, 0.0625]  # two: 2 x 0.031 >= 0.05
    assert statistics.verdict(family) == statistics.CANNOT_DECIDE
    assert all(t.seeds_needed >= 7 for t in family)
    higher = statistics.paired_test("quat", other, other - 0.1 * (1 + np.arange(6)))
    assert statistics.verdict([higher]) == statistics.REFUTED
    assert statistics.verdict([lower, higher]) == statistics.CANNOT_DECIDE  # Holm: 0.0625 each


def test_the_cannot_decide_sentence_names_the_smallest_p_and_the_seeds_needed() -> None:
    assert undecidable(3, 1) == (
        "3 seeds cannot decide: the smallest p an exact test can give with 3 paired seeds is 0.250 "
        "(6 seeds are needed for p < 0.05)."
    )
    assert undecidable(6, 2) == (
        f"6 seeds cannot decide: the smallest p an exact test can give with 6 paired seeds is "
        f"{fmt(0.03125, 3)}, 0.0625 after Holm's correction over 2 comparisons (7 seeds are needed for a "
        "corrected p < 0.05)."
    )
    assert undecidable(6, 1) is None and undecidable(7, 2) is None and undecidable(0, 1) is None


# --------------------------------------------------------------------------------------------------
# The pairwise comparison, paired by seed
# --------------------------------------------------------------------------------------------------


def scores(value: float) -> Scores:
    errors = PoseErrors(Statistics(*[value] * 6), Statistics(*[value] * 6))
    return Scores(errors, errors, KittiError(None, None))


def network(label: str, values: np.ndarray, sequences: list[str]) -> Column:
    """A configuration whose every error on (seed, sequence) is ``values[seed, sequence]``."""
    results = [{s: scores(float(v)) for s, v in zip(sequences, row, strict=True)} for row in values]
    return Column(label, NETWORK, [f"seed={i}" for i in range(len(values))], results)


def test_pairwise_comparison_pairs_seed_means_and_corrects_over_the_pairs_of_a_metric() -> None:
    rng = np.random.default_rng(11)
    sequences = [f"{i:02d}" for i in range(5)]
    base = 1.0 + rng.normal(0, 0.05, (8, 5))
    b, c = base + 0.1 + rng.normal(0, 0.02, (8, 5)), base + rng.normal(0, 0.05, (8, 5))
    columns = [network("a", base, sequences), network("b", b, sequences), network("c", c, sequences)]
    del columns[2].results[3]["04"]  # one seed misses a sequence: 04 leaves every seed's mean of a-c
    found = [c for c in compare(columns) if c.metric == "RPE trans RMSE [m]"]
    assert [(c.a, c.b) for c in found] == [("a", "b"), ("a", "c"), ("b", "c")]
    p = []
    for c in found:
        x, y = ({"a": 0, "b": 1, "c": 2}[k] for k in (c.a, c.b))
        keep = [0, 1, 2, 3] if "c" in (c.a, c.b) else [0, 1, 2, 3, 4]
        means = [np.array([[r[sequences[j]].rpe.trans.rmse for j in keep] for r in columns[k].results])
                 for k in (x, y)]  # fmt: skip
        d = means[0].mean(axis=1) - means[1].mean(axis=1)
        assert c.test.n == 8 and c.sequences == [sequences[j] for j in keep]
        assert c.test.mean_diff == pytest.approx(d.mean(), rel=1e-12)
        p.append(statistics.seed_p(d)[0])
        assert c.test.p_value == pytest.approx(wilcoxon(d, method="exact").pvalue, abs=1e-12)
        assert c.comparisons == 3
    assert [c.test.holm_p for c in found] == pytest.approx(list(statistics.holm(p)), abs=1e-15)
    assert found[0].verdict == "yes" and found[0].test.holm_p < 0.05  # a is 0.1 lower on every seed
    rows = comparison_csv_rows(found).rows
    assert [r[3] for r in rows] == [8, 8, 8] and rows[1][4] == "00;01;02;03"


def test_pairwise_comparison_says_when_the_seeds_cannot_decide() -> None:
    sequences = ["00", "01"]
    base = np.array([[1.0, 1.1], [1.2, 1.3], [1.4, 1.2]])
    found = compare([network("a", base, sequences), network("b", base + 0.5, sequences)])
    assert [c.verdict for c in found] == ["cannot decide with 3 seeds"] * 3
    assert all(c.test.n == 3 and c.test.p_value == 0.25 for c in found)
    single = compare([network("a", base[:1], sequences), network("b", base[:1] + 0.5, sequences)])
    assert single[0].verdict == "n/a (one seed: no seed-noise estimate)"


# --------------------------------------------------------------------------------------------------
# Equivalence as a verdict: known numbers
# --------------------------------------------------------------------------------------------------


def with_relative_effect(effect: float, sd: float, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(claimed, other) of n seeds whose relative differences (claimed - other) / other have exactly the
    mean ``effect`` and sample SD ``sd``; ``other`` is a seed-level error near 0.1 m."""
    rng = np.random.default_rng(seed)
    z = rng.standard_normal(n)
    z = (z - z.mean()) / z.std(ddof=1)
    other = 0.1 * (1 + 0.2 * rng.random(n))
    return other * (1 + effect + sd * z), other


SEEDS_TRIED = range(8)
"""Random draws of each known case: the verdict must hold for every one."""


@pytest.mark.parametrize("draw", SEEDS_TRIED)
def test_minus_ten_percent_with_two_percent_sd_is_supported_at_ten_seeds(draw: int) -> None:
    x, y = with_relative_effect(-0.10, 0.02, 10, draw)
    tests = statistics.corrected(
        [statistics.paired_test("euler", x, y), statistics.paired_test("quat", x, y)]
    )
    assert [statistics.decide(t) for t in tests] == [statistics.SUPPORTED] * 2
    assert statistics.verdict(tests) == statistics.SUPPORTED
    assert tests[0].rel_mean == pytest.approx(-0.10, abs=1e-12) and tests[0].rel_high < -0.05


@pytest.mark.parametrize("draw", SEEDS_TRIED)
def test_zero_with_one_percent_sd_is_equivalent_within_five_percent_at_ten_seeds(draw: int) -> None:
    x, y = with_relative_effect(0.0, 0.01, 10, draw)
    test = statistics.corrected([statistics.paired_test("euler", x, y)])[0]
    assert statistics.decide(test) == statistics.EQUIVALENT and test.tost_p < 0.05
    assert -0.05 < test.rel_low < test.rel_high < 0.05
    assert statistics.verdict_text(statistics.verdict([test])) == "equivalent within ±5 %"
    wide = statistics.corrected([statistics.paired_test("euler", x, y, margin=0.002)])[0]
    assert statistics.decide(wide) == statistics.CANNOT_DECIDE  # the same numbers, a margin of ±0.2 %


@pytest.mark.parametrize("draw", SEEDS_TRIED)
def test_zero_with_twenty_percent_sd_cannot_decide_and_states_the_seeds_needed(draw: int) -> None:
    x, y = with_relative_effect(0.0, 0.20, 10, draw)
    test = statistics.corrected([statistics.paired_test("euler", x, y)])[0]
    assert statistics.decide(test) == statistics.CANNOT_DECIDE
    z = norm.ppf(0.95) + norm.ppf(0.8)
    assert (
        test.seeds_equivalence == math.ceil((z * 0.20 / 0.05) ** 2) == 99
    )  # mean 0: room of the whole margin
    assert math.isfinite(test.seeds_needed) and test.seeds_needed > 10
    assert seeds_needed_text(test.seeds_equivalence) == "99"


@pytest.mark.parametrize("draw", SEEDS_TRIED)
def test_p_values_and_intervals_equal_scipys(draw: int) -> None:
    x, y = with_relative_effect(-0.03, 0.05, 10, draw)
    t = statistics.paired_test("euler", x, y, margin=0.04)
    d, r = x - y, (x - y) / y
    assert t.p_value == pytest.approx(wilcoxon(d, method="exact").pvalue, rel=1e-12, abs=1e-12)
    ci = ttest_1samp(d, 0.0).confidence_interval(0.95)
    assert (t.ci_low, t.ci_high) == (pytest.approx(ci.low, abs=1e-12), pytest.approx(ci.high, abs=1e-12))
    ci90 = ttest_1samp(r, 0.0).confidence_interval(0.90)
    assert (t.rel_low, t.rel_high) == (
        pytest.approx(ci90.low, abs=1e-12),
        pytest.approx(ci90.high, abs=1e-12),
    )
    tost = max(
        ttest_1samp(r, -0.04, alternative="greater").pvalue, ttest_1samp(r, 0.04, alternative="less").pvalue
    )
    assert t.tost_p == pytest.approx(tost, rel=1e-12, abs=1e-12)
    assert (t.tost_p < 0.05) == (t.rel_low > -0.04 and t.rel_high < 0.04)  # TOST = the 90 % interval inside


def test_equivalence_comes_first_then_the_corrected_difference() -> None:
    x, y = with_relative_effect(-0.02, 0.002, 10, 0)  # significantly lower, yet within ±5 %
    test = statistics.corrected([statistics.paired_test("euler", x, y)])[0]
    assert test.holm_p < 0.05 and statistics.decide(test) == statistics.EQUIVALENT
    strict = statistics.corrected([statistics.paired_test("euler", x, y, margin=0.01)])[0]
    assert statistics.decide(strict) == statistics.SUPPORTED
    higher = statistics.corrected([statistics.paired_test("euler", y * 1.2, y)])[0]
    assert statistics.decide(higher) == statistics.REFUTED


def test_combining_comparisons_with_equivalence() -> None:
    s, r, e, c, p = (statistics.SUPPORTED, statistics.REFUTED, statistics.EQUIVALENT,
                     statistics.CANNOT_DECIDE, statistics.PARTLY)  # fmt: skip
    assert statistics.combine([e, e]) == e
    assert statistics.combine([s, e]) == p and statistics.combine([p, s]) == p
    assert statistics.combine([e, c]) == c and statistics.combine([e, r]) == r
    assert statistics.verdict_text(p, 0.02) == "lower than some, equivalent to the others within ±2 %"
    assert statistics.seeds_for_equivalence(0.06, 0.01) == math.inf  # outside the margin already
    assert math.isnan(statistics.tost_p(np.array([0.01])))
