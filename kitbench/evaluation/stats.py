"""The statistics a report quotes: rates with Wilson intervals and summaries of distributions."""

from __future__ import annotations

import math

import numpy as np

Z95 = 1.959963984540054  # two-sided 95% normal quantile


def wilson_interval(successes: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion: unlike the normal approximation it stays inside [0, 1]
    and is honest at 0/N and N/N, which is where policies on small suites often land."""
    if trials <= 0:
        return 0.0, 1.0
    p = successes / trials
    z2 = z * z
    centre = (p + z2 / (2 * trials)) / (1 + z2 / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials)) / (1 + z2 / trials)
    # at 0/N and N/N the bound is exactly 0 or 1; the subtraction leaves ~1e-18 (0/200: 1.7e-18), which put a
    # point's lower error bar below zero and made matplotlib refuse to draw it
    lo = 0.0 if successes <= 0 else max(0.0, centre - half)
    hi = 1.0 if successes >= trials else min(1.0, centre + half)
    return lo, hi


def rate(successes: int, trials: int) -> dict:
    lo, hi = wilson_interval(successes, trials)
    return {
        "count": int(successes),
        "episodes": int(trials),
        "rate": successes / trials if trials else 0.0,
        "ci95": [lo, hi],
    }


def describe(values) -> dict | None:
    """Mean, spread and quantiles of a sample (None when empty)."""
    v = np.asarray(list(values), dtype=np.float64)
    if v.size == 0:
        return None
    q = np.quantile(v, [0.1, 0.25, 0.5, 0.75, 0.9])
    return {
        "n": int(v.size),
        "mean": float(v.mean()),
        "std": float(v.std()),
        "min": float(v.min()),
        "p10": float(q[0]),
        "p25": float(q[1]),
        "median": float(q[2]),
        "p75": float(q[3]),
        "p90": float(q[4]),
        "max": float(v.max()),
    }


def prediction_interval(
    successes: list[int], episodes: list[int], new_episodes: int, level: float = 0.95
) -> tuple[float, float]:
    """Where one new run of `new_episodes` episodes (a new training seed, scored the same way) is expected to land,
    given runs that scored `successes[i]` of `episodes[i]`: the new run's rates y/N that a test of "it shares the
    published runs' rate" does not reject at `level`. The test's variance holds the new run's sampling error, the
    pooled rate's and the spread between runs beyond their sampling error (the method of moments), under Student's
    t with k - 1 degrees of freedom for k runs (the normal quantile and no spread for one run). Its sampling errors
    are taken at the rate the published runs and the new one share under that test, as Krishnamoorthy and Peng's
    joint-sampling interval does (J. Statist. Plann. Inference 141 (2011) 1709-1718), not at the published rate
    alone, which leaves no room at 0/n or n/n (docs/studies/prediction-interval.md)."""
    from scipy import stats  # type: ignore[import-untyped]

    k = len(successes)
    total, trials = sum(successes), sum(episodes)
    p = total / trials
    between = 0.0
    if k > 1:
        rates = [s / n for s, n in zip(successes, episodes, strict=True)]
        sampling = float(np.mean([p * (1 - p) / n for n in episodes]))
        between = max(0.0, float(np.var(rates, ddof=1)) - sampling)
    y = np.arange(new_episodes + 1)
    shared = (total + y) / (trials + new_episodes)
    binomial = shared * (1 - shared)
    run = between + binomial / new_episodes  # the new run's rate about the true mean
    mean = (between + binomial / (trials / k)) / k  # the pooled rate's own error
    quantile = float(stats.t.ppf(0.5 + level / 2, k - 1) if k > 1 else stats.norm.ppf(0.5 + level / 2))
    # never empty: the count nearest the published rate lies within half a count of it, inside the test's bound
    kept = np.flatnonzero((y / new_episodes - p) ** 2 <= quantile**2 * (run + mean))
    return float(kept[0] / new_episodes), float(kept[-1] / new_episodes)
