"""The sequential test of `kitbench race` by simulation: `python bench/sequential_sim.py [options]`.

Each cell simulates `--runs` races (default 10,000) of policy A at success rate p_A against B at p_A - d, on at
most `--max-pairs` seeds (200, the largest shipped suite), looked at every `--block` seeds (10, the race's
default), at `--alpha` (0.05). It prints per cell:

- the false-decision rate: any decision at d = 0, a decision for B at d > 0 (must be <= alpha); beside it, at
  d = 0, the rate of the naive alternative, McNemar's exact test at alpha repeated at every look;
- the power (a decision for A within the seeds) and the median seeds the race used (an undecided race uses all);
- at d = 15 points, the seeds a fixed-N exact McNemar test needs for the same power (the smallest N whose power,
  computed exactly from the binomial distributions of the discordant seeds and of their split, reaches the
  simulated power of the race, or 99% where the race's is higher), and the ratio of the race's median to it.

Paired outcomes: the same seed gives both policies the same initial state, so a seed hard for one tends to be hard
for the other. Each seed has a latent difficulty shared by both: A succeeds when sqrt(rho) z + sqrt(1 - rho) e_A <
Phi^-1(p_A), B likewise with its own e_B (a Gaussian copula, latent correlation `--rho`, default 0, 0.5 and 0.8).
The test's error bound does not depend on it; the seeds needed do (fewer discordant seeds, more lopsided).

`--spending 0.5,0.75,1,1.5` instead compares the exponents rho of the test's spending function alpha * t^rho (the
false-decision rate, and at d = 15 the power, the median seeds and the cells within 0.6 of the fixed-N test),
which is how `kitbench.evaluation.sequential.SPENDING` was chosen.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import stats  # type: ignore[import-untyped]

from kitbench.evaluation.sequential import SPENDING, decisions

RATES = (0.5, 0.7, 0.9, 0.95, 0.99)
DIFFERENCES = (0.0, 0.05, 0.10, 0.20)
RHOS = (0.0, 0.5, 0.8)
POWER_MATCHED = 0.15
MATCH_CAP = 0.99  # the most power a fixed-N test is matched to


def pair_probabilities(p_a: float, p_b: float, rho: float) -> tuple[float, float]:
    """(P(only A succeeds), P(only B succeeds)) on one seed under the Gaussian copula with latent correlation rho."""
    qa, qb = stats.norm.ppf(p_a), stats.norm.ppf(p_b)
    if rho == 0.0:
        both = p_a * p_b
    else:
        both = float(stats.multivariate_normal(mean=[0, 0], cov=[[1, rho], [rho, 1]]).cdf([qa, qb]))
    return max(p_a - both, 0.0), max(p_b - both, 0.0)


def simulate(p_a_only: float, p_b_only: float, runs: int, pairs: int, rng: np.random.Generator):
    """Cumulative counts of seeds only A and only B succeeded on, after each seed: two (runs, pairs) arrays."""
    u = rng.random((runs, pairs))
    a_only = u < p_a_only
    b_only = (u >= p_a_only) & (u < p_a_only + p_b_only)
    return np.cumsum(a_only, axis=1, dtype=np.int32), np.cumsum(b_only, axis=1, dtype=np.int32)


def looks(pairs: int, block: int) -> np.ndarray:
    """The seed counts the race looks at: every block, and the last seed."""
    return np.unique(np.r_[np.arange(block, pairs + 1, block), pairs])


def race(a_only, b_only, alpha: float, block: int, rho: float = SPENDING):
    """Each simulated race's outcome: (decision: +1 A, -1 B, 0 none; seeds used), on a suite of as many seeds
    as the simulation has."""
    at = looks(a_only.shape[1], block)
    a, b = a_only[:, at - 1], b_only[:, at - 1]
    decided = decisions(a, a + b, at / a_only.shape[1], alpha, rho)
    hit = decided != 0
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), -1)
    rows = np.arange(len(first))
    decision = np.where(first >= 0, decided[rows, np.maximum(first, 0)], 0)
    used = np.where(first >= 0, at[np.maximum(first, 0)], at[-1])
    return decision, used


def mcnemar_critical(max_discordant: int, alpha: float) -> np.ndarray:
    """c[k]: with k discordant seeds the exact two-sided McNemar test rejects when the larger side has >= c[k]
    (k + 1 where it never can)."""
    c = np.full(max_discordant + 1, 0, dtype=np.int64)
    for k in range(max_discordant + 1):
        s = np.arange(k + 1)
        p = np.minimum(1.0, 2 * stats.binom.cdf(np.minimum(s, k - s), k, 0.5))
        ok = s[(p <= alpha) & (s * 2 > k)]
        c[k] = ok.min() if ok.size else k + 1
    return c


def naive_repeated(a_only, b_only, alpha: float, block: int) -> np.ndarray:
    """Whether McNemar's exact fixed-N test, applied at every look, ever rejects (either direction)."""
    at = looks(a_only.shape[1], block)
    a, b = a_only[:, at - 1], b_only[:, at - 1]
    critical = mcnemar_critical(int((a + b).max()), alpha)
    return (np.maximum(a, b) >= critical[a + b]).any(axis=1)


def fixed_n_power(p_a_only: float, p_b_only: float, n: int, critical: np.ndarray) -> float:
    """Exact power of the fixed-N McNemar test for A on n seeds: sum over k discordant of P(k) P(A side >= c[k])."""
    d = p_a_only + p_b_only
    theta = p_a_only / d
    k = np.arange(n + 1)
    return float(np.sum(stats.binom.pmf(k, n, d) * stats.binom.sf(critical[k] - 1, k, theta)))


def power_matched_n(p_a_only: float, p_b_only: float, power: float, alpha: float, limit: int = 3000) -> int | None:
    """The fewest seeds a fixed-N exact McNemar test needs to decide for A with at least `power`."""
    critical = mcnemar_critical(limit, alpha)
    for n in range(1, limit + 1):
        if fixed_n_power(p_a_only, p_b_only, n, critical) >= power:
            return n
    return None


def run_cells(
    runs: int, pairs: int, block: int, alpha: float, rhos, seed: int, spending: float = SPENDING, matched: bool = True
) -> list[dict]:
    rng = np.random.default_rng(seed)
    rows = []
    for rho in rhos:
        for p_a in RATES:
            for d in sorted({*DIFFERENCES, POWER_MATCHED}):
                p_b = p_a - d
                pa_only, pb_only = pair_probabilities(p_a, p_b, rho)
                a, b = simulate(pa_only, pb_only, runs, pairs, rng)
                decision, used = race(a, b, alpha, block, spending)
                row = {
                    "rho": rho,
                    "p_a": p_a,
                    "d": d,
                    "false": float(np.mean(decision != 0) if d == 0 else np.mean(decision < 0)),
                    "power": float(np.mean(decision > 0)),
                    "median": float(np.median(used)),
                    "naive": float(np.mean(naive_repeated(a, b, alpha, block))) if d == 0 else None,
                    "fixed_n": None,
                }
                if matched and d == POWER_MATCHED and row["power"] > 0:
                    # a power of 1 in simulation says "at least 1 - 1/runs or so": matched as MATCH_CAP
                    row["fixed_n"] = power_matched_n(pa_only, pb_only, min(row["power"], MATCH_CAP), alpha)
                rows.append(row)
    return rows


def _cell(value: float | None, percent: bool = True) -> str:
    if value is None:
        return "–"
    return f"{value:.1%}" if percent else f"{value:g}"


def print_table(rows: list[dict], alpha: float) -> None:
    """Three tables: the false-decision rates, the power and seeds used, the power-matched comparison at d = 15."""
    cells = sorted({(r["rho"], r["p_a"]) for r in rows})
    at = {(r["rho"], r["p_a"], r["d"]): r for r in rows}
    ds = sorted({r["d"] for r in rows})
    print(f"False decisions (any at d = 0, for B at d > 0), at most alpha = {alpha:g}:\n")
    print("| rho | p_A | " + " | ".join(f"d = {d:.0%}" for d in ds) + " | naive: McNemar at every look, d = 0 |")
    print("|---|---|" + "---|" * (len(ds) + 1))
    for rho, p in cells:
        falses = " | ".join(_cell(at[rho, p, d]["false"]) for d in ds)
        print(f"| {rho:g} | {p:.0%} | {falses} | {_cell(at[rho, p, 0.0]['naive'])} |")
    print("\nPower (a decision for A within the seeds) and, in brackets, the median seeds used:\n")
    print("| rho | p_A | " + " | ".join(f"d = {d:.0%}" for d in ds if d > 0) + " |")
    print("|---|---|" + "---|" * (len(ds) - 1))
    for rho, p in cells:
        print(f"| {rho:g} | {p:.0%} | " + " | ".join(
            f"{at[rho, p, d]['power']:.1%} ({at[rho, p, d]['median']:g})" for d in ds if d > 0) + " |")  # fmt: skip
    print(f"\nAt d = {POWER_MATCHED:.0%}: the race's median seeds against a fixed-N exact McNemar test of the same "
          "power:\n")  # fmt: skip
    print("| rho | p_A | power | median seeds | fixed-N McNemar, same power | ratio |")
    print("|---|---|---|---|---|---|")
    ratios = []
    for rho, p in cells:
        r = at[rho, p, POWER_MATCHED]
        ratio = r["median"] / r["fixed_n"] if r["fixed_n"] else None
        ratios += [ratio] if ratio is not None else []
        shown = f"{ratio:.2f}" if ratio is not None else "–"
        print(f"| {rho:g} | {p:.0%} | {r['power']:.1%} | {r['median']:g} | {_cell(r['fixed_n'], False)} | {shown} |")
    worst = max(r["false"] for r in rows)
    print(f"\nworst false-decision rate {worst:.2%} (alpha {alpha:g}); at d = {POWER_MATCHED:.0%}: median/fixed-N "
          f"ratio {min(ratios):.2f}-{max(ratios):.2f} (median {np.median(ratios):.2f}), <= 0.6 in "
          f"{sum(r <= 0.6 for r in ratios)} of {len(ratios)} cells")  # fmt: skip


def compare_spending(exponents, runs: int, pairs: int, block: int, alpha: float, rhos, seed: int) -> None:
    print(
        "| rho | worst false-decision rate | at d = 15: power (mean over cells) | median seeds (mean) | "
        "median / fixed-N: cells <= 0.6 | worst cell |"
    )
    print("|---|---|---|---|---|---|")
    for rho in exponents:
        rows = run_cells(runs, pairs, block, alpha, rhos, seed, rho)
        at = [r for r in rows if r["d"] == POWER_MATCHED]
        ratios = [r["median"] / r["fixed_n"] for r in at if r["fixed_n"]]
        print(
            f"| {rho:g} | {max(r['false'] for r in rows):.2%} | {np.mean([r['power'] for r in at]):.1%} | "
            f"{np.mean([r['median'] for r in at]):.1f} | {sum(x <= 0.6 for x in ratios)} of {len(ratios)} | "
            f"{max(ratios):.2f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10_000, help="races per cell")
    parser.add_argument("--max-pairs", type=int, default=200, help="seeds in the suite")
    parser.add_argument("--block", type=int, default=10, help="seeds between looks")
    parser.add_argument("--alpha", type=float, default=0.05)
    parser.add_argument("--rho", default=",".join(map(str, RHOS)), help="latent correlations, comma-separated")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--spending", default=None, help="compare these exponents rho of the spending function")
    args = parser.parse_args()
    rhos = [float(r) for r in args.rho.split(",")]
    started = time.monotonic()
    if args.spending:
        exponents = [float(p) for p in args.spending.split(",")]
        compare_spending(exponents, args.runs, args.max_pairs, args.block, args.alpha, rhos, args.seed)
    else:
        rows = run_cells(args.runs, args.max_pairs, args.block, args.alpha, rhos, args.seed)
        print_table(rows, args.alpha)
    print(f"({args.runs} races a cell, at most {args.max_pairs} seeds, a look every {args.block}, "
          f"alpha {args.alpha:g}; {time.monotonic() - started:.0f} s)")  # fmt: skip


if __name__ == "__main__":
    main()
