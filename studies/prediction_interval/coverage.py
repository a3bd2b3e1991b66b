"""How often does a new training seed land inside the interval `kitbench reproduce` prints for it?

    python studies/prediction_interval/coverage.py [--draws 4000] [--level 0.95]

Two intervals, each for one new run of m episodes given published runs: `shared`, kitbench's
(`kitbench.evaluation.stats.prediction_interval`: the sampling errors at the rate the published runs and the new one
share under the test), and `published`, the same test with the sampling errors at the published rate alone (the
interval `kitbench reproduce` printed before). For one published run it prints the exact coverage (every published
count and every new count, weighted by their binomial probabilities) at true rates from 0.5% to 99.5%; for three
published seeds whose true rates spread about the mean (a beta distribution with the given standard deviation
between seeds), the coverage over `--draws` simulated draws of three published seeds and a new one. The level is
what both promise: a rate well under it is an interval that calls a fair draw "below" or "above".
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy import stats

from kitbench.evaluation.stats import prediction_interval

RATES = (0.005, 0.02, 0.05, 0.2, 0.5, 0.8, 0.95, 0.98, 0.995)


def published_rate_interval(
    successes: list[int], episodes: list[int], new_episodes: int, level: float = 0.95
) -> tuple[float, float]:
    """The same interval with every sampling error at the published pooled rate: a normal approximation about it,
    zero wide at 0/n and n/n."""
    k = len(successes)
    p = sum(successes) / sum(episodes)
    binomial = p * (1 - p)
    between = 0.0
    if k > 1:
        rates = [s / n for s, n in zip(successes, episodes, strict=True)]
        between = max(0.0, float(np.var(rates, ddof=1)) - float(np.mean([binomial / n for n in episodes])))
    run = between + binomial / new_episodes
    mean = (between + binomial / (sum(episodes) / k)) / k
    quantile = stats.t.ppf(0.5 + level / 2, k - 1) if k > 1 else stats.norm.ppf(0.5 + level / 2)
    half = float(quantile) * math.sqrt(run + mean)
    return max(0.0, p - half), min(1.0, p + half)


METHODS = {"shared": prediction_interval, "published": published_rate_interval}


def exact_coverage(method, rate: float, n: int, m: int, level: float) -> float:
    """P(new count inside the interval) with one published run of n episodes and a new one of m, at a true rate."""
    new = np.arange(m + 1)
    new_mass = stats.binom.pmf(new, m, rate)
    covered = 0.0
    for count, mass in zip(range(n + 1), stats.binom.pmf(np.arange(n + 1), n, rate), strict=True):
        if mass < 1e-12:
            continue
        lo, hi = method([count], [n], m, level)
        inside = (new / m >= lo - 1e-12) & (new / m <= hi + 1e-12)
        covered += mass * float(new_mass[inside].sum())
    return covered


def simulated_coverage(method, rate: float, spread: float, n: int, m: int, level: float, draws: int) -> float:
    """The share of `draws` where a new seed lands inside the interval from three published seeds, every seed's true
    rate drawn from a beta distribution of mean `rate` and standard deviation `spread`."""
    rng = np.random.default_rng(0)
    concentration = rate * (1 - rate) / spread**2 - 1  # a beta's a + b for this mean and spread
    seeds = rng.beta(rate * concentration, (1 - rate) * concentration, size=(draws, 4))
    counts = rng.binomial(np.array([n, n, n, m]), seeds)
    hits = 0
    for row in counts:
        lo, hi = method([int(c) for c in row[:3]], [n, n, n], m, level)
        hits += lo - 1e-12 <= row[3] / m <= hi + 1e-12
    return hits / draws


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=4000)
    parser.add_argument("--level", type=float, default=0.95)
    args = parser.parse_args(argv)
    print(f"one published run, exact coverage at {args.level:.0%}")
    print("| true rate | " + " | ".join(f"{name}, n = m = {n}" for n in (100, 200) for name in METHODS) + " |")
    print("|---" * 5 + "|")
    for rate in RATES:
        cells = [exact_coverage(f, rate, n, n, args.level) for n in (100, 200) for f in METHODS.values()]
        print(f"| {rate:.1%} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")
    print(f"\nthree published seeds of 100 episodes, a new one of 100, {args.draws} draws each")
    print("| true rate | between-seed sd | " + " | ".join(METHODS) + " |")
    print("|---" * 4 + "|")
    for rate, spread in ((0.02, 0.01), (0.5, 0.1), (0.9, 0.05), (0.97, 0.02), (0.99, 0.005)):
        cells = [simulated_coverage(f, rate, spread, 100, 100, args.level, args.draws) for f in METHODS.values()]
        print(f"| {rate:.1%} | {spread:.3f} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")


if __name__ == "__main__":
    main()
