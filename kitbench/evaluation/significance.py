"""Significance of a difference between two success rates: exact p-values (Fisher's, Barnard's, McNemar's) and
Newcombe's intervals of the difference, unpaired and paired (see `compare.py` for which one a comparison uses)."""

from __future__ import annotations

import math

from kitbench.errors import KitbenchError, check_choice
from kitbench.evaluation.stats import wilson_interval

UNPAIRED_TESTS = ("fisher", "barnard")


def check_alpha(value: float | str) -> float:
    """The significance level, a number strictly between 0 and 1 (a string is parsed, for the command line)."""
    try:
        alpha = float(value)
    except (TypeError, ValueError):
        alpha = math.nan
    if not 0.0 < alpha < 1.0:  # also refuses nan
        raise KitbenchError(f"alpha must be a number between 0 and 1 (exclusive), got {value!r}")
    return alpha


def _square_and_add(pa: float, a_ci: tuple[float, float], pb: float, b_ci: tuple[float, float], phi: float):
    """Newcombe's square-and-add interval for pb - pa from the two proportions' own intervals; `phi` is the
    correlation between the two estimates (0 for independent samples)."""
    (la, ua), (lb, ub) = a_ci, b_ci
    d = pb - pa
    # each side combines the distances towards that side: B's lower arm with A's upper one, and vice versa
    lower = d - math.sqrt(max(0.0, (pb - lb) ** 2 + (ua - pa) ** 2 - 2 * phi * (pb - lb) * (ua - pa)))
    upper = d + math.sqrt(max(0.0, (ub - pb) ** 2 + (pa - la) ** 2 - 2 * phi * (ub - pb) * (pa - la)))
    return max(-1.0, lower), min(1.0, upper)


def newcombe_interval(a_count: int, a_n: int, b_count: int, b_n: int) -> tuple[float, float]:
    """95% interval of b_count/b_n - a_count/a_n for independent samples: Newcombe's hybrid score interval
    (method 10 of Newcombe 1998), which like the Wilson intervals it is built from behaves at 0/N and N/N."""
    pa, pb = a_count / a_n, b_count / b_n
    return _square_and_add(pa, wilson_interval(a_count, a_n), pb, wilson_interval(b_count, b_n), 0.0)


def newcombe_paired_interval(a_only: int, b_only: int, both: int, neither: int) -> tuple[float, float]:
    """95% interval of rate(B) - rate(A) on the same episodes (Newcombe 1998, paired method 10): the
    square-and-add interval with the correlation phi of the paired outcomes, continuity-corrected towards 0 when
    positive and set to 0 when a margin is empty, as Newcombe defines it."""
    n = a_only + b_only + both + neither
    a, b = both + a_only, both + b_only  # A's and B's counts
    margins = a * (n - a) * b * (n - b)
    cross = both * neither - a_only * b_only
    phi = 0.0
    if margins and not 0 <= cross <= n / 2:
        phi = (cross - n / 2 if cross > 0 else cross) / math.sqrt(margins)
    return _square_and_add(a / n, wilson_interval(a, n), b / n, wilson_interval(b, n), phi)


def _scipy_stats():
    """scipy.stats, imported when a test runs (it takes a while to import)."""
    # scipy has no type information (no py.typed marker, no stubs installed)
    from scipy import stats  # type: ignore[import-untyped]

    return stats


def unpaired_p(a_count: int, a_n: int, b_count: int, b_n: int, test: str = "fisher") -> float:
    """Two-sided p-value that A and B have the same rate, from the 2x2 table of outcome by report."""
    stats = _scipy_stats()
    check_choice("test", test, UNPAIRED_TESTS)
    # one column per report: Barnard's test takes the columns as the two samples (Fisher's is symmetric)
    table = [[a_count, b_count], [a_n - a_count, b_n - b_count]]
    if test == "fisher":
        return float(stats.fisher_exact(table).pvalue)
    return float(stats.barnard_exact(table).pvalue)


def mcnemar_p(a_only: int, b_only: int) -> float:
    """Two-sided exact McNemar p-value: under "no difference" each discordant seed is equally likely to favour
    A or B, so `b_only` is Binomial(a_only + b_only, 1/2). The concordant seeds carry no information."""
    if a_only + b_only == 0:
        return 1.0
    return float(_scipy_stats().binomtest(b_only, a_only + b_only, 0.5).pvalue)
