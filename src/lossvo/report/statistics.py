"""The statistics behind a sweep report's comparisons and claims: convergence epochs, Wilcoxon
signed-rank p-values, paired tests and the verdict rule, and the architecture x loss interaction test.

A claim says that one configuration (the *claimed* one, e.g. the chordal loss) is lower than every other
on some quantity (an error in m or rad, a convergence epoch). Each other configuration is paired with it
(over (seed, sequence) or over seeds) and tested with a two-sided Wilcoxon signed-rank test. The verdict
(:func:`verdict`) is one of :data:`VERDICTS`:

- **supported**: the claimed configuration's mean is lower than every other's and every p < alpha;
- **contradicted**: some other configuration's mean is lower with p < alpha;
- **not distinguishable at this n**: anything else (too few pairs, p >= alpha, ties, a missing pair).

Where a sweep varies the architecture, :func:`interaction_test` asks whether the losses' effects depend on
the architecture (an exact randomisation test on the between-architecture differences, seeds as blocks) and
:func:`interaction_verdict` words its outcome.

Nothing here reads files or formats markdown.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import wilcoxon

SUPPORTED = "supported"
CONTRADICTED = "contradicted"
NOT_DISTINGUISHABLE = "not distinguishable at this n"
VERDICTS = (SUPPORTED, CONTRADICTED, NOT_DISTINGUISHABLE)
ALPHA = 0.05
"""The significance level of every test in the report."""
CONVERGENCE_TOLERANCE = 0.1


def convergence_epoch(
    epochs: np.ndarray, values: np.ndarray, tolerance: float = CONVERGENCE_TOLERANCE, mode: str = "min"
) -> int | None:
    """The first epoch whose value comes within ``tolerance`` (relative) of the best value of the curve.

    For ``mode="min"`` that is the first ``value <= best + tolerance * |best|`` (``best * 1.1`` for a
    positive best and the default 10 %); for ``"max"`` the first ``value >= best - tolerance * |best|``.
    Non-finite values are ignored.

    Args:
        epochs: (E,) epoch numbers, in any counting (returned as given), in increasing order.
        values: (E,) the curve (e.g. ``val/score``, unitless).
        tolerance: relative distance to the best value (0.1: 10 %).
        mode: ``"min"`` (lower is better) or ``"max"``.

    Returns:
        The epoch number, or None if the curve has no finite value.
    """
    if mode not in ("min", "max"):
        raise ValueError(f"mode: expected 'min' or 'max', got {mode!r}")
    epochs, values = np.asarray(epochs), np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    if not finite.any():
        return None
    epochs, values = epochs[finite], values[finite]
    best = values.min() if mode == "min" else values.max()
    margin = tolerance * abs(best)
    close = values <= best + margin if mode == "min" else values >= best - margin
    return int(epochs[np.argmax(close)])


def wilcoxon_p(differences: np.ndarray) -> float:
    """Two-sided Wilcoxon signed-rank p-value of paired differences (P,) (1.0 if all are zero)."""
    if not np.any(differences != 0):
        return 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ties or zeros: scipy warns, then permutes or approximates
        return float(wilcoxon(differences).pvalue)


def smallest_p(n: int) -> float:
    """The smallest two-sided p-value an exact (or exhaustive permutation) Wilcoxon signed-rank test can
    give with ``n`` pairs: ``2 / 2**n`` (all differences of one sign), 1.0 for n = 0 (0.25 for n = 3)."""
    return min(1.0, 2.0 / 2.0**n) if n > 0 else 1.0


@dataclass(frozen=True)
class PairedTest:
    """One configuration against another (``versus``) on paired values: ``n`` pairs, the means over those
    pairs (in the quantity's unit), the median of the differences (this - versus), the number of pairs
    where this one is lower and the two-sided Wilcoxon p-value (NaN for n = 0)."""

    versus: str
    n: int
    mean: float
    versus_mean: float
    p_value: float
    median_diff: float = math.nan
    lower: int = 0

    @property
    def claimed_lower(self) -> bool:
        return self.n > 0 and self.mean < self.versus_mean


def paired_test(versus: str, claimed: np.ndarray, other: np.ndarray) -> PairedTest:
    """The one paired test of the report: values (P,) of one configuration against (P,) of ``versus``,
    two-sided Wilcoxon signed-rank test on the differences."""
    claimed, other = np.asarray(claimed, dtype=np.float64), np.asarray(other, dtype=np.float64)
    if claimed.shape != other.shape or claimed.ndim != 1:
        raise ValueError(f"paired values must be two (P,) arrays, got {claimed.shape} and {other.shape}")
    if claimed.size == 0:
        return PairedTest(versus, 0, math.nan, math.nan, math.nan)
    d = claimed - other
    return PairedTest(versus, int(claimed.size), float(claimed.mean()), float(other.mean()), wilcoxon_p(d),
                      float(np.median(d)), int((d < 0).sum()))  # fmt: skip


def verdict(tests: Sequence[PairedTest], alpha: float = ALPHA) -> str:
    """The verdict on "the claimed configuration is lower than every other" from its paired tests.

    Contradicted if some other configuration has a lower mean with p < ``alpha``; supported if there is
    at least one test and in every test the claimed mean is lower with p < ``alpha``; otherwise not
    distinguishable at this n.
    """
    if any(t.n > 0 and t.versus_mean < t.mean and t.p_value < alpha for t in tests):
        return CONTRADICTED
    if tests and all(t.claimed_lower and t.p_value < alpha for t in tests):
        return SUPPORTED
    return NOT_DISTINGUISHABLE


def combine(verdicts: Sequence[str]) -> str:
    """One verdict from several (e.g. one per error metric): contradicted if any is, supported if all
    are (and there is at least one), otherwise not distinguishable at this n."""
    if CONTRADICTED in verdicts:
        return CONTRADICTED
    if verdicts and all(v == SUPPORTED for v in verdicts):
        return SUPPORTED
    return NOT_DISTINGUISHABLE


# --------------------------------------------------------------------------------------------------
# Architecture x loss interaction
# --------------------------------------------------------------------------------------------------

INTERACTION = "the losses' effects differ between the architectures (interaction)"
NO_INTERACTION = "no interaction detected at this n"
CANNOT_DECIDE = "cannot decide at this n"
INTERACTION_VERDICTS = (INTERACTION, NO_INTERACTION, CANNOT_DECIDE)
MAX_ENUMERATED = 1_000_000
"""Relabellings an exact :func:`interaction_test` enumerates at most; above, it draws :data:`DRAWS`."""
DRAWS = 100_000


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
    architecture x loss interaction of two architectures A, B with seeds as blocks.

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
