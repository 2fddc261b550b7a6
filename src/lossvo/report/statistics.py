"""The statistics behind a sweep report's comparisons and claims: convergence epochs, the seed-level paired
test (:func:`paired_test`: exact Wilcoxon or sign-flip p and the TOST equivalence test on the per-seed
relative differences, effect, t-intervals, seeds needed for either outcome), Holm's correction, the verdict
rule (:func:`decide`, :func:`verdict`) and the architecture x loss interaction test. Seeds are the
unit: a configuration's value on one seed is one number, and configurations are paired by seed (the cells
of one seed share one network). :func:`cells_test` over (seed, sequence) cells is indicative only. No I/O.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import norm, permutation_test, ttest_1samp, wilcoxon

from lossvo.console import UserError

SUPPORTED = "supported"
REFUTED = "refuted"
EQUIVALENT = "equivalent"
PARTLY = "lower than some, equivalent to the others"
CANNOT_DECIDE = "cannot decide at this n"
VERDICTS = (SUPPORTED, REFUTED, EQUIVALENT, PARTLY, CANNOT_DECIDE)
"""A comparison's verdict (:func:`decide`): lower (supported), higher (refuted), equivalent within the
margin, or undecided; a family's (:func:`combine`) may also be :data:`PARTLY`."""
ALPHA = 0.05
"""The significance level of every test in the report."""
MARGIN = 0.05
"""The default equivalence margin δ: a relative difference inside ±δ counts as no difference that matters."""
CONFIDENCE = 0.95
"""The level of every confidence interval in the report."""
POWER = 0.8
"""The power :func:`seeds_needed` asks for."""
CONVERGENCE_TOLERANCE = 0.1
MAX_ENUMERATED = 1_000_000
"""Sign patterns (:func:`sign_flip_p`) or relabellings (:func:`interaction_test`) enumerated at most; above,
:data:`DRAWS` random ones are drawn (fixed seed)."""
DRAWS = 100_000
WILCOXON = "exact Wilcoxon"
SIGN_FLIP = "exact sign-flip"
SIGN_FLIP_DRAWN = "sign-flip, random"
"""The methods of :func:`seed_p`: no ties or zeros, ties or zeros, ties or zeros with too many patterns."""


def convergence_epoch(
    epochs: np.ndarray, values: np.ndarray, tolerance: float = CONVERGENCE_TOLERANCE, mode: str = "min"
) -> int | None:
    """The first of ``epochs`` (E,), as given, whose finite value of the curve ``values`` (E,) comes within
    ``tolerance`` (relative) of its best: ``value <= best + tolerance * |best|`` for ``mode="min"``,
    ``>= best - tolerance * |best|`` for ``"max"``; None if no value is finite."""
    if mode not in ("min", "max"):
        raise UserError(f"mode: expected 'min' or 'max', got {mode!r}")
    epochs, values = np.asarray(epochs), np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    if not finite.any():
        return None
    epochs, values = epochs[finite], values[finite]
    best = values.min() if mode == "min" else values.max()
    margin = tolerance * abs(best)
    close = values <= best + margin if mode == "min" else values >= best - margin
    return int(epochs[np.argmax(close)])


# --------------------------------------------------------------------------------------------------
# p-values
# --------------------------------------------------------------------------------------------------


def wilcoxon_p(differences: np.ndarray) -> float:
    """Two-sided Wilcoxon signed-rank p-value of paired differences (P,) by scipy's default method
    (exact for small P without ties, else a normal approximation); 1.0 if all are zero."""
    if not np.any(differences != 0):
        return 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ties or zeros: scipy warns, then permutes or approximates
        return float(wilcoxon(differences).pvalue)


def has_ties(differences: np.ndarray) -> bool:
    """Whether paired differences (n,) hold a zero or two equal absolute values (Wilcoxon ties)."""
    magnitudes = np.abs(np.asarray(differences, dtype=np.float64))
    return bool(np.any(magnitudes == 0) or np.unique(magnitudes).size < magnitudes.size)


def sign_flip_p(differences: np.ndarray, max_enumerated: int = MAX_ENUMERATED) -> tuple[float, bool]:
    """Two-sided sign-flip p-value of the mean of paired differences (n,) (``scipy.stats.permutation_test``,
    ``permutation_type="samples"``) and whether it is exact: above ``max_enumerated`` of the 2^n patterns,
    :data:`DRAWS` random ones (fixed seed). 1.0 for n < 2 or all zeros."""
    d = np.asarray(differences, dtype=np.float64)
    if d.size < 2 or not np.any(d != 0):  # one difference: both patterns' |sum| are equal
        return 1.0, True
    exact = 2.0**d.size <= max_enumerated
    result = permutation_test(
        (d,),
        lambda x, axis: np.mean(x, axis=axis),
        permutation_type="samples",
        vectorized=True,
        n_resamples=np.inf if exact else DRAWS,
        alternative="two-sided",
        rng=np.random.default_rng(0),
    )
    return min(1.0, float(result.pvalue)), exact


def seed_p(differences: np.ndarray) -> tuple[float, str]:
    """The report's two-sided p-value of paired per-seed differences (n,) and its method: the exact
    Wilcoxon signed-rank test (:data:`WILCOXON`) without ties or zeros, else the sign-flip permutation
    test of the mean (:data:`SIGN_FLIP`, or :data:`SIGN_FLIP_DRAWN` above :data:`MAX_ENUMERATED`
    patterns). NaN for n = 0; 1.0 if all differences are zero."""
    d = np.asarray(differences, dtype=np.float64)
    if d.size == 0:
        return math.nan, SIGN_FLIP
    if has_ties(d):
        p, exact = sign_flip_p(d)
        return p, SIGN_FLIP if exact else SIGN_FLIP_DRAWN
    return float(wilcoxon(d, alternative="two-sided", method="exact").pvalue), WILCOXON


def smallest_p(n: int) -> float:
    """The smallest two-sided p-value an exact (or exhaustive permutation) test of n paired differences
    can give: ``2 / 2**n`` (all differences of one sign), 1.0 for n = 0 (0.25 for n = 3)."""
    return min(1.0, 2.0 / 2.0**n) if n > 0 else 1.0


def smallest_holm_p(n: int, comparisons: int = 1) -> float:
    """The smallest Holm-corrected p of a family of ``comparisons`` tests on n paired seeds each."""
    return min(1.0, max(1, comparisons) * smallest_p(n))


def can_decide(n: int, comparisons: int = 1, alpha: float = ALPHA) -> bool:
    """Whether some outcome of n paired seeds gives a Holm-corrected p < ``alpha`` in a family of
    ``comparisons`` tests."""
    return smallest_holm_p(n, comparisons) < alpha


def min_seeds(comparisons: int = 1, alpha: float = ALPHA) -> int:
    """The fewest paired seeds that :func:`can_decide` in a family of ``comparisons`` tests (6 for one
    comparison at 0.05, 7 for two or three, 8 for four)."""
    n = 1
    while not can_decide(n, comparisons, alpha):
        n += 1
    return n


def holm(p_values: Sequence[float]) -> np.ndarray:
    """Holm's step-down adjusted p-values (m,) of a family of m p-values, in the given order:
    q_(i) = min(1, max_{j <= i} (m - j + 1) p_(j)) over the ascending p_(j). A NaN p counts in m as 1.0
    and stays NaN."""
    p = np.asarray(p_values, dtype=np.float64)
    m = p.size
    filled = np.where(np.isnan(p), 1.0, p)
    order = np.argsort(filled, kind="stable")
    adjusted = np.empty(m)
    adjusted[order] = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * filled[order]))
    return np.where(np.isnan(p), math.nan, adjusted)


# --------------------------------------------------------------------------------------------------
# The effect and the seeds needed
# --------------------------------------------------------------------------------------------------


def t_interval(differences: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The two-sided t-interval of the mean of paired differences (n,), in their unit
    (``scipy.stats.ttest_1samp(d).confidence_interval(confidence)``); (NaN, NaN) for n < 2, (mean, mean)
    where every difference is the same (scipy gives NaN there)."""
    d = np.asarray(differences, dtype=np.float64)
    if d.size < 2:
        return math.nan, math.nan
    if np.all(d == d[0]):
        return float(d[0]), float(d[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # scipy's precision note on near-equal values
        ci = ttest_1samp(d, 0.0).confidence_interval(confidence)
    return float(ci.low), float(ci.high)


def relative_differences(claimed: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Per-pair relative differences (n,): (claimed - other) / |other|, unitless (-0.1: 10 % lower);
    pairs where ``other`` is 0 are left out."""
    claimed, other = np.asarray(claimed, dtype=np.float64), np.asarray(other, dtype=np.float64)
    kept = other != 0
    return (claimed[kept] - other[kept]) / np.abs(other[kept])


def tost_p(relative: np.ndarray, margin: float = MARGIN) -> float:
    """The p-value of the two one-sided t-tests (TOST) of equivalence of the mean of ``relative`` (n,) within
    ±``margin``: the larger p of ``ttest_1samp`` against -margin (greater) and +margin (less). NaN for
    n < 2; where every value is the same, 0 inside the margin and 1 outside."""
    r = np.asarray(relative, dtype=np.float64)
    if r.size < 2:
        return math.nan
    if np.all(r == r[0]):
        return 0.0 if abs(float(r[0])) < margin else 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # scipy's precision note on near-equal values
        above = float(ttest_1samp(r, -margin, alternative="greater").pvalue)
        below = float(ttest_1samp(r, margin, alternative="less").pvalue)
    return max(above, below)


def seeds_needed(
    mean: float, sd: float, comparisons: int = 1, alpha: float = ALPHA, power: float = POWER
) -> float:
    """The paired seeds that would detect a mean difference ``mean`` at the spread ``sd`` (the SD of the
    per-seed differences, same unit) in a family of ``comparisons`` tests.

    n = ceil(((z_{1-alpha/(2m)} + z_{power}) · sd / |mean|)^2) (m = ``comparisons``; the normal
    approximation of a paired two-sided test at the Bonferroni level alpha / m), at least
    :func:`min_seeds` (m, alpha). inf where ``mean`` is 0 (no effect observed); NaN where ``mean`` or
    ``sd`` is not finite (fewer than two seeds).
    """
    m = max(1, comparisons)
    return _normal_seeds(float(norm.ppf(1 - alpha / (2 * m))), power, sd, abs(mean), min_seeds(m, alpha))


def seeds_for_equivalence(
    mean: float, sd: float, margin: float = MARGIN, alpha: float = ALPHA, power: float = POWER
) -> float:
    """The paired seeds at which TOST would show equivalence within ±``margin`` if the true relative
    difference were ``mean`` with spread ``sd`` (both unitless, per seed).

    n = ceil(((z_{1-alpha} + z_{power}) · sd / (margin - |mean|))^2) (normal approximation; each one-sided
    test at alpha, no correction: equivalence to every other configuration is an intersection-union
    test), at least 2. inf where |mean| >= margin (the observed difference is itself outside the margin);
    NaN where ``mean`` or ``sd`` is not finite.
    """
    return _normal_seeds(float(norm.ppf(1 - alpha)), power, sd, margin - abs(mean), 2)


def _normal_seeds(z_alpha: float, power: float, sd: float, room: float, fewest: int) -> float:
    """ceil(((z_alpha + z_power) · sd / room)²), at least ``fewest``; inf where ``room`` <= 0 (and finite),
    NaN where ``sd`` or ``room`` is not finite."""
    if not (math.isfinite(room) and math.isfinite(sd)):
        return math.nan
    if room <= 0:
        return math.inf
    z = z_alpha + float(norm.ppf(power))
    return float(max(math.ceil((z * sd / room) ** 2), fewest))


# --------------------------------------------------------------------------------------------------
# The paired test and the verdict
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PairedTest:
    """One configuration against another (``versus``) on n paired values (seeds, or (seed, sequence) cells
    for :func:`cells_test`), in the quantity's unit: means, two-sided p and its method, the differences'
    (this - versus) median and SD (ddof = 1), the pairs where this one is lower, the 95 % t-interval of the
    mean difference, Holm's p and :func:`seeds_needed` of its family (:func:`corrected`); on the relative
    differences r = (this - versus) / |versus| (unitless): mean, SD, 90 % t-interval, TOST p within
    ±``margin`` and :func:`seeds_for_equivalence`."""

    versus: str
    n: int
    mean: float
    versus_mean: float
    p_value: float
    median_diff: float = math.nan
    lower: int = 0
    method: str = WILCOXON
    sd_diff: float = math.nan
    ci_low: float = math.nan
    ci_high: float = math.nan
    holm_p: float = math.nan
    seeds_needed: float = math.nan
    rel_mean: float = math.nan
    rel_sd: float = math.nan
    rel_low: float = math.nan
    rel_high: float = math.nan
    tost_p: float = math.nan
    margin: float = MARGIN
    seeds_equivalence: float = math.nan

    @property
    def claimed_lower(self) -> bool:
        return self.n > 0 and self.mean < self.versus_mean

    @property
    def mean_diff(self) -> float:
        """The mean paired difference this - versus (the difference of the means)."""
        return self.mean - self.versus_mean

    @property
    def relative(self) -> float:
        """:attr:`mean_diff` over |versus mean| (NaN where that is 0 or undefined)."""
        return self.mean_diff / abs(self.versus_mean) if self.versus_mean else math.nan

    @property
    def relative_ci(self) -> tuple[float, float]:
        """The interval divided by |versus mean| (taken as fixed)."""
        scale = abs(self.versus_mean) if self.versus_mean else math.nan
        return self.ci_low / scale, self.ci_high / scale


def _checked(claimed: np.ndarray, other: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    claimed, other = np.asarray(claimed, dtype=np.float64), np.asarray(other, dtype=np.float64)
    if claimed.shape != other.shape or claimed.ndim != 1:
        raise ValueError(f"paired values must be two (P,) arrays, got {claimed.shape} and {other.shape}")
    return claimed, other


def paired_test(
    versus: str, claimed: np.ndarray, other: np.ndarray, margin: float = MARGIN, alpha: float = ALPHA
) -> PairedTest:
    """The report's paired test: per-seed values (n,) of one configuration against (n,) of ``versus``
    (paired by position): p by :func:`seed_p` on the differences, the effect, its intervals,
    TOST within ±``margin`` and the seeds needed for either outcome, as a family of one."""
    claimed, other = _checked(claimed, other)
    if claimed.size == 0:
        return PairedTest(versus, 0, math.nan, math.nan, math.nan, margin=margin)
    d, r = claimed - other, relative_differences(claimed, other)
    p, method = seed_p(d)
    sd = float(d.std(ddof=1)) if d.size > 1 else math.nan
    rel_mean = float(r.mean()) if r.size else math.nan
    rel_sd = float(r.std(ddof=1)) if r.size > 1 else math.nan
    low, high = t_interval(d)
    rel_low, rel_high = t_interval(r, 1 - 2 * alpha)
    means = float(claimed.mean()), float(other.mean())
    return PairedTest(
        versus,
        int(d.size),
        *means,
        p,
        float(np.median(d)),
        int((d < 0).sum()),
        method,
        sd,
        low,
        high,
        p,
        seeds_needed(means[0] - means[1], sd, 1, alpha),
        rel_mean,
        rel_sd,
        rel_low,
        rel_high,
        tost_p(r, margin),
        margin,
        seeds_for_equivalence(rel_mean, rel_sd, margin, alpha),
    )


def cells_test(versus: str, claimed: np.ndarray, other: np.ndarray) -> PairedTest:
    """The secondary test over (seed, sequence) cells (P,): scipy's default two-sided Wilcoxon
    (:func:`wilcoxon_p`). The cells of one seed share one network, so it is indicative only."""
    claimed, other = _checked(claimed, other)
    if claimed.size == 0:
        return PairedTest(versus, 0, math.nan, math.nan, math.nan, method="Wilcoxon over cells")
    d = claimed - other
    means = float(claimed.mean()), float(other.mean())
    median, lower = float(np.median(d)), int((d < 0).sum())
    return PairedTest(versus, int(d.size), *means, wilcoxon_p(d), median, lower, "Wilcoxon over cells")


def corrected(tests: Sequence[PairedTest], alpha: float = ALPHA) -> list[PairedTest]:
    """A family of tests (one claim's comparisons on one quantity) with its Holm-corrected p-values
    (:func:`holm`) and the seeds needed to detect each difference for m = ``len(tests)`` comparisons."""
    adjusted = holm([x.p_value for x in tests])
    return [
        replace(x, holm_p=float(q), seeds_needed=seeds_needed(x.mean_diff, x.sd_diff, len(tests), alpha))
        for x, q in zip(tests, adjusted, strict=True)
    ]


def decide(test: PairedTest, alpha: float = ALPHA) -> str:
    """One comparison's verdict, from a test of a corrected family (:func:`corrected`):
    :data:`EQUIVALENT` where the (1 - 2 alpha) interval of the relative difference lies inside ±margin
    (TOST p < alpha); else :data:`SUPPORTED` (lower) or :data:`REFUTED` (higher) where the Holm p <
    alpha; else :data:`CANNOT_DECIDE`."""
    if test.n > 1 and test.tost_p < alpha:
        return EQUIVALENT
    if test.n > 0 and test.holm_p < alpha:
        return SUPPORTED if test.claimed_lower else REFUTED
    return CANNOT_DECIDE


def combine(verdicts: Sequence[str]) -> str:
    """One verdict from several (a claim's comparisons, or its quantities): refuted if any is;
    supported, equivalent if all are (and there is at least one); :data:`PARTLY` if every one is
    supported, equivalent or partly; otherwise cannot decide at this n."""
    if REFUTED in verdicts:
        return REFUTED
    for same in (SUPPORTED, EQUIVALENT):
        if verdicts and all(v == same for v in verdicts):
            return same
    if verdicts and all(v in (SUPPORTED, EQUIVALENT, PARTLY) for v in verdicts):
        return PARTLY
    return CANNOT_DECIDE


def verdict(tests: Sequence[PairedTest], alpha: float = ALPHA) -> str:
    """The verdict on "the claimed configuration is lower than every other" from its paired tests as one
    family: :func:`decide` on each test after Holm's correction over ``tests``, then :func:`combine`."""
    return combine([decide(t, alpha) for t in corrected(tests, alpha)])


def verdict_text(verdict_: str, margin: float = MARGIN) -> str:
    """A verdict as the report words it: ``equivalent within ±5 %`` for :data:`EQUIVALENT` (and in
    :data:`PARTLY`), else the verdict itself."""
    return f"{verdict_} within ±{100 * margin:g} %" if verdict_ in (EQUIVALENT, PARTLY) else verdict_


# --------------------------------------------------------------------------------------------------
# Architecture x loss interaction
# --------------------------------------------------------------------------------------------------

INTERACTION = "the losses' effects differ between the architectures (interaction)"
NO_INTERACTION = "no interaction detected at this n"
INTERACTION_VERDICTS = (INTERACTION, NO_INTERACTION, CANNOT_DECIDE)


@dataclass(frozen=True)
class InteractionTest:
    """The architecture x loss interaction test on the differences (L losses, S seeds): the interaction
    ``statistic`` F (NaN where undefined), its randomisation ``p_value``, the number of within-seed
    relabellings ``permutations`` ((L!)^S when ``exact``, else the random ones drawn) and
    ``smallest_p``, the smallest p the exact test can give at this L and S."""

    losses: int
    seeds: int
    statistic: float
    p_value: float
    permutations: int
    exact: bool
    smallest_p: float

    @property
    def can_decide(self) -> bool:
        """Whether p < :data:`ALPHA` is attainable at this n."""
        return self.smallest_p < ALPHA


def interaction_smallest_p(losses: int, seeds: int) -> float:
    """The smallest p of the exact :func:`interaction_test` with ``losses`` L and ``seeds`` S: (L!)^(1-S),
    since the L! relabellings that permute every seed's losses alike leave F unchanged (1/36 for 3 x 3,
    1/6 for 3 losses x 2 seeds, 1/4 for 2 x 3, 1/2 for 2 x 2); 1.0 for L < 2 or S < 2."""
    if losses < 2 or seeds < 2:
        return 1.0
    return float(math.factorial(losses)) ** (1 - seeds)


def interaction_f(differences: np.ndarray) -> float:
    """The interaction F of (L, S) between-architecture differences d (see :func:`interaction_test`):
    inf where the residual is 0 and the interaction is not, NaN where both are 0 or L, S < 2."""
    d = np.asarray(differences, dtype=np.float64)
    losses, seeds = d.shape
    if losses < 2 or seeds < 2:
        return math.nan
    loss_means, seed_means = d.mean(axis=1, keepdims=True), d.mean(axis=0, keepdims=True)
    between = seeds * float(((loss_means - d.mean()) ** 2).sum())
    residual = float(((d - loss_means - seed_means + d.mean()) ** 2).sum())
    scale = float((d**2).sum()) * 1e-24
    if residual <= scale:
        return math.inf if between > scale else math.nan
    return (between / (losses - 1)) / (residual / ((losses - 1) * (seeds - 1)))


def interaction_test(differences: np.ndarray, max_enumerated: int = MAX_ENUMERATED) -> InteractionTest:
    """Does the effect of the loss depend on the architecture? An exact randomisation test of the
    architecture x loss interaction of two architectures A, B with seeds as blocks. Written here because
    ``scipy.stats.permutation_test`` enumerates all (L!)^S relabellings, L! times more than the distinct
    ones counted below (it cannot fix the first seed), too many to be exact at 10 seeds.

    Let y[a, l, s] be a score (e.g. a seed's mean RPE over the held-out sequences) of architecture a, loss
    l = 1..L and seed s = 1..S, and d[l, s] = y[B, l, s] - y[A, l, s]. With no interaction, d[l, s] =
    c_s + e[l, s]: a seed's differences (c_s absorbs the architectures' difference and anything a seed
    shares) do not depend on the loss, so the loss labels of each seed's L differences are exchangeable.
    The statistic is the interaction F of the two-way ANOVA of y with seeds as blocks (architecture x loss
    against the architecture x loss x seed residual), written in d as

        F = [S sum_l (dbar_l. - dbar)^2 / (L - 1)]
            / [sum_ls (d_ls - dbar_l. - dbar_.s + dbar)^2 / ((L - 1)(S - 1))]

    (dbar_l.: loss l's mean over seeds, dbar_.s: seed s's mean over losses, dbar: the mean of all),

    and p is the fraction of the (L!)^S relabellings (every seed's losses permuted independently, the
    observed one included) whose F is at least the observed one. Each seed's sum of squares about its mean
    is the same under every relabelling, so F grows with sum_l (sum_s d_ls)^2, which is counted instead.
    Permuting every seed's losses alike leaves F unchanged, so p >= (L!)^(1-S)
    (:func:`interaction_smallest_p`): with 3 losses and 3 seeds p can reach 1/36, with 2 seeds or 2 losses
    never 0.05. Above ``max_enumerated`` relabellings p is estimated from :data:`DRAWS` random ones (fixed
    seed) as (1 + hits) / (1 + DRAWS) and ``exact`` is False.

    Args:
        differences: (L, S) finite d[l, s], in the score's unit; one row per loss, one column per seed.
        max_enumerated: the most relabellings enumerated (those fixing the first seed: (L!)^(S-1)).

    Returns:
        The test; p = 1 and F = NaN for L < 2 or S < 2.
    """
    d = np.asarray(differences, dtype=np.float64)
    if d.ndim != 2 or not np.isfinite(d).all():
        raise ValueError(f"differences: expected a finite (losses, seeds) array, got shape {d.shape}")
    losses, seeds = d.shape
    smallest = interaction_smallest_p(losses, seeds)
    if losses < 2 or seeds < 2:
        return InteractionTest(losses, seeds, math.nan, 1.0, 1, True, smallest)
    observed = float((d.sum(axis=1) ** 2).sum())
    tolerance = 1e-9 * float((np.abs(d).sum(axis=1) ** 2).sum())
    orders = np.array(list(itertools.permutations(range(losses))))  # (L!, L)
    count = len(orders) ** (seeds - 1)
    if count <= max_enumerated:
        sums = d[:, 0][None, :]  # seed 0 fixed: each class of L! equal relabellings counted once
        for s in range(1, seeds):
            sums = (sums[:, None, :] + d[orders, s][None, :, :]).reshape(-1, losses)
        hits = int(((sums**2).sum(axis=1) >= observed - tolerance).sum())
        p, permutations, exact = hits / count, count * len(orders), True
    else:
        rng = np.random.default_rng(0)
        picks = rng.integers(len(orders), size=(DRAWS, seeds))  # (draws, S) a permutation per seed
        columns = d.T[np.arange(seeds)[None, :, None], orders[picks]]  # (draws, S, L)
        hits = int(((columns.sum(axis=1) ** 2).sum(axis=1) >= observed - tolerance).sum())
        p, permutations, exact = (1 + hits) / (1 + DRAWS), DRAWS, False
    return InteractionTest(losses, seeds, interaction_f(d), p, permutations, exact, smallest)


def interaction_verdict(test: InteractionTest, alpha: float = ALPHA) -> str:
    """:data:`INTERACTION` if p < ``alpha``; otherwise :data:`CANNOT_DECIDE` where the smallest attainable p
    is not below ``alpha``, else :data:`NO_INTERACTION` (which is not evidence that the rankings agree)."""
    if test.p_value < alpha:
        return INTERACTION
    if test.smallest_p >= alpha:
        return CANNOT_DECIDE
    return NO_INTERACTION
