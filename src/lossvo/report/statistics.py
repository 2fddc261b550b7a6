"""The statistics of the report's comparisons and claims: convergence epochs, the paired test over seeds,
Holm's correction, the verdict rule and the architecture x loss interaction test. No I/O; the rules and
their rationale: docs/report.md (*Seeds are the unit*, *A sweep of several architectures*)."""

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
ALPHA = 0.05
"""The significance level of every test in the report."""
MARGIN = 0.05
"""The default equivalence margin δ on relative differences."""
CONFIDENCE = 0.95
POWER = 0.8
"""The power :func:`seeds_needed` asks for."""
CONVERGENCE_TOLERANCE = 0.1
MAX_ENUMERATED = 1_000_000
"""Sign patterns or relabellings enumerated at most; above, :data:`DRAWS` random ones (fixed seed)."""
DRAWS = 100_000
WILCOXON = "exact Wilcoxon"
SIGN_FLIP = "exact sign-flip"
SIGN_FLIP_DRAWN = "sign-flip, random"


def convergence_epoch(
    epochs: np.ndarray, values: np.ndarray, tolerance: float = CONVERGENCE_TOLERANCE, mode: str = "min"
) -> int | None:
    """The first of ``epochs`` (E,) whose finite value (E,) is within ``tolerance`` · |best| of the best;
    None if no value is finite."""
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


def has_ties(differences: np.ndarray) -> bool:
    """Whether paired differences (n,) hold a zero or two equal absolute values."""
    magnitudes = np.abs(np.asarray(differences, dtype=np.float64))
    return bool(np.any(magnitudes == 0) or np.unique(magnitudes).size < magnitudes.size)


def sign_flip_p(differences: np.ndarray, max_enumerated: int = MAX_ENUMERATED) -> tuple[float, bool]:
    """Two-sided sign-flip p-value of the mean of paired differences (n,) and whether it is exact (at most
    ``max_enumerated`` of the 2^n patterns); 1.0 for n < 2 or all zeros."""
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
    """Two-sided p of per-seed differences (n,) and its method: exact Wilcoxon, or the sign-flip test
    with ties or zeros. NaN for n = 0."""
    d = np.asarray(differences, dtype=np.float64)
    if d.size == 0:
        return math.nan, SIGN_FLIP
    if has_ties(d):
        p, exact = sign_flip_p(d)
        return p, SIGN_FLIP if exact else SIGN_FLIP_DRAWN
    return float(wilcoxon(d, alternative="two-sided", method="exact").pvalue), WILCOXON


def smallest_p(n: int) -> float:
    """The smallest two-sided p an exact test of n paired differences can give: 2 / 2^n."""
    return min(1.0, 2.0 / 2.0**n) if n > 0 else 1.0


def smallest_holm_p(n: int, comparisons: int = 1) -> float:
    """The smallest Holm-corrected p of a family of ``comparisons`` tests on n paired seeds each."""
    return min(1.0, max(1, comparisons) * smallest_p(n))


def can_decide(n: int, comparisons: int = 1, alpha: float = ALPHA) -> bool:
    """Whether some outcome of n paired seeds gives a Holm p < ``alpha`` among ``comparisons`` tests."""
    return smallest_holm_p(n, comparisons) < alpha


def min_seeds(comparisons: int = 1, alpha: float = ALPHA) -> int:
    """The fewest paired seeds that :func:`can_decide` (6 for one comparison at 0.05, 7 for two)."""
    n = 1
    while not can_decide(n, comparisons, alpha):
        n += 1
    return n


def holm(p_values: Sequence[float]) -> np.ndarray:
    """Holm's step-down adjusted p-values (m,), in the given order; a NaN p counts as 1.0 and stays NaN."""
    p = np.asarray(p_values, dtype=np.float64)
    m = p.size
    filled = np.where(np.isnan(p), 1.0, p)
    order = np.argsort(filled, kind="stable")
    adjusted = np.empty(m)
    adjusted[order] = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * filled[order]))
    return np.where(np.isnan(p), math.nan, adjusted)


def t_interval(differences: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The t-interval of the mean of differences (n,), in their unit; NaN for n < 2, (d, d) where all
    equal (scipy gives NaN there)."""
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
    """(claimed - other) / |other| per pair (n,), unitless; pairs where ``other`` is 0 are left out."""
    claimed, other = np.asarray(claimed, dtype=np.float64), np.asarray(other, dtype=np.float64)
    kept = other != 0
    return (claimed[kept] - other[kept]) / np.abs(other[kept])


def tost_p(relative: np.ndarray, margin: float = MARGIN) -> float:
    """TOST p of the mean of ``relative`` (n,) lying within ±``margin``; NaN for n < 2, 0 or 1 where
    every value is the same."""
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


def seeds_needed(mean: float, sd: float, comparisons: int = 1) -> float:
    """The paired seeds that would detect a mean difference ``mean`` at the per-seed SD ``sd`` among
    ``comparisons`` tests, at least :func:`min_seeds`; inf where ``mean`` is 0, NaN where not finite."""
    m = max(1, comparisons)
    return _normal_seeds(float(norm.ppf(1 - ALPHA / (2 * m))), sd, abs(mean), min_seeds(m))


def seeds_for_equivalence(mean: float, sd: float, margin: float = MARGIN) -> float:
    """The paired seeds at which TOST would show equivalence if the relative difference were ``mean`` with
    per-seed SD ``sd``, at least 2; inf where |mean| >= margin, NaN where not finite."""
    return _normal_seeds(float(norm.ppf(1 - ALPHA)), sd, margin - abs(mean), 2)


def _normal_seeds(z_alpha: float, sd: float, room: float, fewest: int) -> float:
    if not (math.isfinite(room) and math.isfinite(sd)):
        return math.nan
    if room <= 0:
        return math.inf
    z = z_alpha + float(norm.ppf(POWER))
    return float(max(math.ceil((z * sd / room) ** 2), fewest))


@dataclass(frozen=True)
class PairedTest:
    """One configuration against ``versus`` on n paired values, in the quantity's unit (``ci_*``: 95 %
    t-interval of this - versus); ``rel_*`` on the relative differences (90 % t-interval)."""

    versus: str
    n: int
    mean: float
    versus_mean: float
    p_value: float
    lower: int = 0
    method: str = WILCOXON
    sd_diff: float = math.nan
    ci_low: float = math.nan
    ci_high: float = math.nan
    rel_mean: float = math.nan
    rel_low: float = math.nan
    rel_high: float = math.nan
    tost_p: float = math.nan
    margin: float = MARGIN
    seeds_equivalence: float = math.nan
    holm_p: float = math.nan
    seeds_needed: float = math.nan

    @property
    def claimed_lower(self) -> bool:
        return self.n > 0 and self.mean < self.versus_mean

    @property
    def mean_diff(self) -> float:
        """The mean paired difference this - versus."""
        return self.mean - self.versus_mean

    @property
    def relative(self) -> float:
        """:attr:`mean_diff` over |versus mean| (NaN where that is 0)."""
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


def paired_test(versus: str, claimed: np.ndarray, other: np.ndarray, margin: float = MARGIN) -> PairedTest:
    """The report's paired test of per-seed values (n,) against ``versus``'s (n,), as a family of one."""
    claimed, other = _checked(claimed, other)
    if claimed.size == 0:
        return PairedTest(versus, 0, math.nan, math.nan, math.nan, margin=margin)
    d, r = claimed - other, relative_differences(claimed, other)
    p, method = seed_p(d)
    sd = float(d.std(ddof=1)) if d.size > 1 else math.nan
    rel_mean = float(r.mean()) if r.size else math.nan
    rel_sd = float(r.std(ddof=1)) if r.size > 1 else math.nan
    means = float(claimed.mean()), float(other.mean())
    equivalence = seeds_for_equivalence(rel_mean, rel_sd, margin)
    relative = (rel_mean, *t_interval(r, 1 - 2 * ALPHA), tost_p(r, margin), margin, equivalence)
    test = PairedTest(
        versus, int(d.size), *means, p, int((d < 0).sum()), method, sd, *t_interval(d), *relative
    )
    return corrected([test])[0]


def cells_test(versus: str, claimed: np.ndarray, other: np.ndarray) -> PairedTest:
    """The indicative test over (seed, sequence) cells (P,): scipy's default two-sided Wilcoxon; 1.0 if all
    differences are zero."""
    claimed, other = _checked(claimed, other)
    if claimed.size == 0:
        return PairedTest(versus, 0, math.nan, math.nan, math.nan, method="Wilcoxon over cells")
    d, p = claimed - other, 1.0
    if np.any(d != 0):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # ties or zeros: scipy warns, then permutes or approximates
            p = float(wilcoxon(d).pvalue)
    means = float(claimed.mean()), float(other.mean())
    return PairedTest(versus, int(d.size), *means, p, int((d < 0).sum()), "Wilcoxon over cells")


def corrected(tests: Sequence[PairedTest]) -> list[PairedTest]:
    """A family of tests with Holm's p and the seeds needed for m = ``len(tests)`` comparisons."""
    adjusted = holm([x.p_value for x in tests])
    return [
        replace(x, holm_p=float(q), seeds_needed=seeds_needed(x.mean_diff, x.sd_diff, len(tests)))
        for x, q in zip(tests, adjusted, strict=True)
    ]


def decide(test: PairedTest) -> str:
    """One comparison's verdict from a test of a :func:`corrected` family: equivalent (TOST), else
    supported or refuted (Holm p), else cannot decide."""
    if test.n > 1 and test.tost_p < ALPHA:
        return EQUIVALENT
    if test.n > 0 and test.holm_p < ALPHA:
        return SUPPORTED if test.claimed_lower else REFUTED
    return CANNOT_DECIDE


def combine(verdicts: Sequence[str]) -> str:
    """One verdict from several: refuted if any is; supported or equivalent if all are; :data:`PARTLY`
    if each is one of those; otherwise cannot decide."""
    if REFUTED in verdicts:
        return REFUTED
    for same in (SUPPORTED, EQUIVALENT):
        if verdicts and all(v == same for v in verdicts):
            return same
    if verdicts and all(v in (SUPPORTED, EQUIVALENT, PARTLY) for v in verdicts):
        return PARTLY
    return CANNOT_DECIDE


def verdict(tests: Sequence[PairedTest]) -> str:
    """The verdict of paired tests as one family: :func:`combine` of each :func:`decide`."""
    return combine([decide(t) for t in corrected(tests)])


def verdict_text(verdict_: str, margin: float = MARGIN) -> str:
    """A verdict as the report words it: ``equivalent within ±5 %``."""
    return f"{verdict_} within ±{100 * margin:g} %" if verdict_ in (EQUIVALENT, PARTLY) else verdict_


INTERACTION = "the losses' effects differ between the architectures (interaction)"
NO_INTERACTION = "no interaction detected at this n"


@dataclass(frozen=True)
class InteractionTest:
    """The architecture x loss interaction test (L losses, S seeds): F, its randomisation p, the
    relabellings counted ((L!)^S when ``exact``, else those drawn) and the smallest attainable p."""

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


def interaction_f(differences: np.ndarray) -> float:
    """The interaction F of (L, S) differences d: inf where only the residual is 0, NaN where both are
    or L, S < 2."""
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
    """The exact randomisation test of the architecture x loss interaction on d[l, s] = y[B, l, s] -
    y[A, l, s] (L, S) (finite, the score's unit), seeds as blocks: each seed's loss labels permuted
    (docs/report.md). Hand-written: ``scipy.stats.permutation_test`` would enumerate L! times too many
    relabellings. Above ``max_enumerated`` (those fixing the first seed), :data:`DRAWS` random ones."""
    d = np.asarray(differences, dtype=np.float64)
    if d.ndim != 2 or not np.isfinite(d).all():
        raise ValueError(f"differences: expected a finite (losses, seeds) array, got shape {d.shape}")
    losses, seeds = d.shape
    if losses < 2 or seeds < 2:
        return InteractionTest(losses, seeds, math.nan, 1.0, 1, True, 1.0)
    smallest = float(math.factorial(losses)) ** (1 - seeds)  # relabelling all seeds alike leaves F as is
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


def interaction_verdict(test: InteractionTest) -> str:
    """:data:`INTERACTION` if p < :data:`ALPHA`; else cannot decide where no such p is attainable."""
    if test.p_value < ALPHA:
        return INTERACTION
    return NO_INTERACTION if test.can_decide else CANNOT_DECIDE
