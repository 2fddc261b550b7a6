"""The statistics behind a sweep report's comparisons and claims: convergence epochs, Wilcoxon
signed-rank p-values, paired tests and the verdict rule.

A claim says that one configuration (the *claimed* one, e.g. the chordal loss) is lower than every other
on some quantity (an error in m or rad, a convergence epoch). Each other configuration is paired with it
(over (seed, sequence) or over seeds) and tested with a two-sided Wilcoxon signed-rank test. The verdict
(:func:`verdict`) is one of :data:`VERDICTS`:

- **supported**: the claimed configuration's mean is lower than every other's and every p < alpha;
- **contradicted**: some other configuration's mean is lower with p < alpha;
- **not distinguishable at this n**: anything else (too few pairs, p >= alpha, ties, a missing pair).

Nothing here reads files or formats markdown.
"""

from __future__ import annotations

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
