"""A paired comparison of two success rates on the same seeds that may stop at any look (`kitbench race`): an
exact group-sequential McNemar test, its error rate at most alpha however early it stops.

Of the seeds scored so far, the discordant ones (one policy succeeded, the other failed) carry the difference:
under "no difference" each favours A with probability 1/2 whatever the seed's difficulty, independently of which
seeds were discordant. So, given the discordant counts k_1 <= k_2 <= ... at the looks, the number S_j of them
favouring A is a fair random walk observed at those counts, and its law is computed exactly (a convolution of
binomials from look to look). The test spends alpha over the suite (Lan and DeMets 1983, "Discrete sequential
boundaries for clinical trials", Biometrika 70(3):659-663) with the power spending function alpha * t^rho of Kim
and DeMets 1987 (Biometrika 74(1):149-154), t = seeds scored / seeds in the suite: at look j each side's boundary
is the most extreme count whose chance of being reached, on paths that crossed no earlier boundary, keeps that
side's total at most alpha/2 * t_j^rho. So the test decides with probability at most alpha at no difference,
given the discordant counts and so unconditionally, for any look schedule fixed in advance (the race's
`--block`); a decision for the worse policy is at most alpha/2 likely.

Its interval is the same test inverted (repeated confidence intervals: Jennison and Turnbull 2000, "Group
Sequential Methods with Applications to Clinical Trials", ch. 9): theta, the chance a discordant seed favours A, is
kept at a look unless the walk with Binomial(., theta) steps crossed theta's own boundaries there; the intervals
hold the truth at every look at once with probability 1 - alpha, and leave out 1/2 exactly when the test decides.
rate(A) - rate(B) = D (2 theta - 1), D the chance a seed is discordant, which gets Robbins' confidence sequence from
a Beta(1/2, 1/2) mixture over all the seeds (Robbins 1970; Howard, Ramdas, McAuliffe and Sekhon 2021, Ann. Statist.
49(2):1055-1080). The two hold together with probability 1 - alpha by splitting it: `THETA_SHARE` to theta (the
decision), the rest to D.

rho decides when alpha is spent: small, early (decisions on a lopsided start); large, late (power at the suite's
end). `SPENDING` = 0.75 was chosen by simulation (`bench/sequential_sim.py --spending`, docs/evaluation.md)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import brentq  # type: ignore[import-untyped]
from scipy.special import betaln  # type: ignore[import-untyped]
from scipy.stats import binom  # type: ignore[import-untyped]

SPENDING = 0.75  # rho of the spending function alpha * t^rho; see the module docstring
DISCORDANCE_PRIOR = 0.5  # Beta(1/2, 1/2) on D
THETA_SHARE = 0.9  # the share of alpha the decision gets; the rest bounds D for the interval of the difference
SLACK = 1e-12  # rounding in sums of probabilities: a boundary may spend this much more than its share
BISECTIONS = 45  # halvings of theta's bracket for each end of its interval (to ~3e-14)
A_BETTER, B_BETTER, UNDECIDED = "A better", "B better", "no difference detected"


def spent(fraction, alpha: float, rho: float = SPENDING):
    """The error the test may have spent in all when `fraction` of the suite's seeds are scored."""
    return alpha * np.clip(fraction, 0.0, 1.0) ** rho


def _advance(dist: np.ndarray, steps: np.ndarray, theta: float) -> np.ndarray:
    """Each row's law of S after `steps[row]` more discordant seeds (a convolution with Binomial(steps, theta))."""
    width = dist.shape[1]
    if len(dist) == 1:
        step = int(steps[0])
        return np.convolve(dist[0], binom.pmf(np.arange(step + 1), step, theta))[None, :width]
    out = np.zeros_like(dist)
    for step in np.unique(steps):
        rows = steps == step
        block = dist[rows]
        moved = np.zeros_like(block)
        for i, weight in enumerate(binom.pmf(np.arange(step + 1), step, theta)):
            moved[:, i:] += weight * block[:, : width - i]
        out[rows] = moved
    return out


def boundaries(discordant, fractions, alpha: float, theta: float = 0.5, rho: float = SPENDING):
    """The test of theta at each look, for each row of `discordant` (the discordant counts at the looks, one row
    a run; a 1-d sequence is one run): (lower, upper), int arrays of its shape. It rejects at look j when
    S_j <= lower[j] or S_j >= upper[j] (-1 and k_j + 1 where it cannot yet); each side spends at most
    alpha/2 * fractions[j]^rho in all, on the paths that crossed neither boundary at an earlier look."""
    ks = np.atleast_2d(np.asarray(discordant, dtype=np.int64))
    rows, looks = ks.shape
    if looks != len(fractions):
        raise ValueError(f"{looks} looks but {len(fractions)} fractions of the suite")
    if (np.diff(ks, axis=1, prepend=0) < 0).any():
        raise ValueError("discordant counts must not fall from look to look")
    width = int(ks.max(initial=0)) + 2
    dist: np.ndarray = np.zeros((rows, width))
    dist[:, 0] = 1.0
    spent_hi, spent_lo = np.zeros(rows), np.zeros(rows)
    lower, upper = np.empty_like(ks), np.empty_like(ks)
    column = np.arange(width)[None, :]
    previous: np.ndarray = np.zeros(rows, dtype=np.int64)
    for j in range(looks):
        k = ks[:, j]
        dist = _advance(dist, k - previous, theta)
        previous = k
        allowed = float(spent(fractions[j], alpha / 2, rho)) + SLACK
        tail = np.cumsum(dist[:, ::-1], axis=1)[:, ::-1]  # P(S >= u, no earlier crossing); 0 past k: always found
        up = np.minimum(np.argmax(tail <= (allowed - spent_hi)[:, None], axis=1), k + 1)
        if theta == 0.5:  # the fair walk is symmetric, so are its boundaries (bit for bit) and what they spend
            up = np.maximum(up, k // 2 + 1)
            low = k - up
            spent_hi += np.take_along_axis(tail, up[:, None], axis=1)[:, 0]
        else:
            head = np.cumsum(dist, axis=1)  # P(S <= l, no earlier crossing)
            low = np.minimum((head <= (allowed - spent_lo)[:, None]).sum(axis=1) - 1, up - 1)
            spent_hi += np.take_along_axis(tail, up[:, None], axis=1)[:, 0]
            spent_lo += np.where(low >= 0, np.take_along_axis(head, np.maximum(low, 0)[:, None], axis=1)[:, 0], 0.0)
        dist = np.where((column >= up[:, None]) | (column <= low[:, None]), 0.0, dist)
        lower[:, j], upper[:, j] = low, up
    return lower, upper


def decisions(wins_a, discordant, fractions, alpha: float, rho: float = SPENDING) -> np.ndarray:
    """At each look of each run: +1 where the test decides for A, -1 for B, 0 where it does not (arrays as
    `boundaries`'s; a run stops at its first decision)."""
    lower, upper = boundaries(discordant, fractions, THETA_SHARE * alpha, rho=rho)
    s = np.atleast_2d(np.asarray(wins_a, dtype=np.int64))
    return np.where(s >= upper, 1, np.where(s <= lower, -1, 0))


def _mixture_interval(successes: int, trials: int, alpha: float, prior: tuple[float, float]) -> tuple[float, float]:
    """Robbins' confidence sequence for a Bernoulli mean at `trials`: {p : B(a + k, b + n - k) / B(a, b) /
    (p^k (1 - p)^(n - k)) < 1/alpha}, an interval around k/n (the log ratio is convex in p)."""
    if trials == 0:
        return 0.0, 1.0
    a, b = prior
    k, n = successes, trials
    mixture = float(betaln(a + k, b + n - k) - betaln(a, b))
    threshold = -math.log(alpha)

    def excess(p: float) -> float:  # log M(p) - log(1/alpha): negative inside the interval
        null = (k * math.log(p) if k else 0.0) + ((n - k) * math.log1p(-p) if n - k else 0.0)
        return mixture - null - threshold

    centre = k / n
    if excess(min(max(centre, 1e-12), 1 - 1e-12)) >= 0:  # cannot happen with a proper prior; kept honest
        return centre, centre
    tiny = 1e-15
    lo = 0.0 if k == 0 or excess(tiny) < 0 else brentq(excess, tiny, centre, xtol=1e-12)
    hi = 1.0 if k == n or excess(1 - tiny) < 0 else brentq(excess, centre, 1 - tiny, xtol=1e-12)
    return float(lo), float(hi)


def _theta_interval(wins_a: int, discordant: Sequence[int], fractions: Sequence[float], alpha: float):
    """The repeated confidence interval of theta at the last look: the thetas whose own test does not reject
    there, its ends found by bisection from the estimate outwards."""
    k = discordant[-1]
    estimate = wins_a / k if k else 0.5

    def side(theta: float) -> int:  # +1: theta too small for S (S at or over its upper boundary), -1 too large
        lower, upper = boundaries(discordant, fractions, alpha, theta)
        return 1 if wins_a >= upper[0, -1] else -1 if wins_a <= lower[0, -1] else 0

    def end(towards: float, sign: int) -> float:
        if side(towards) != sign:  # the extreme theta itself is kept (no win, or no loss, for A)
            return towards
        inside, outside = estimate, towards
        for _ in range(BISECTIONS):
            middle = (inside + outside) / 2
            if side(middle) == sign:
                outside = middle
            else:
                inside = middle
        return inside  # the last theta seen kept: the end never crosses 1/2 where the test decided

    return end(0.0, 1), end(1.0, -1)


@dataclass(frozen=True)
class Assessment:
    """Where the comparison stands after `pairs` seeds scored by both: `a_only` seeds only A succeeded on,
    `b_only` only B. `difference` is rate(A) - rate(B), `interval` its 1 - alpha interval, valid at every look at
    once; `theta_interval` the chance a discordant seed favours A; `needs`: the discordant seeds one side needed
    at this look to decide (the count past which it cannot yet, k + 1); `spent` the most error the decision may
    have spent so far (its spending function at this look)."""

    pairs: int
    a_only: int
    b_only: int
    alpha: float
    decision: str
    difference: float
    interval: tuple[float, float]
    theta_interval: tuple[float, float]
    needs: int
    spent: float

    @property
    def decided(self) -> bool:
        return self.decision != UNDECIDED

    def to_dict(self) -> dict:
        out = asdict(self)
        out["interval"], out["theta_interval"] = list(self.interval), list(self.theta_interval)
        return out


def assess(looks: Sequence[tuple[int, int, int]], total: int, alpha: float) -> Assessment:
    """The test at the last of `looks` ((pairs, a_only, b_only) at each look so far, in order) on a suite of
    `total` seeds; valid however the looks were spaced, if their spacing did not depend on the outcomes."""
    pairs = [p for p, _, _ in looks]
    if not looks or any(not 0 < p <= total for p in pairs) or any(b <= a for a, b in itertools.pairwise(pairs)):
        raise ValueError(f"looks at {pairs} seeds of {total}: they must rise, within the suite")
    for p, a_only, b_only in looks:
        if not 0 <= a_only + b_only <= p or min(a_only, b_only) < 0:
            raise ValueError(f"{a_only} + {b_only} discordant seeds of {p}")
    n, a_only, b_only = looks[-1]
    discordant = [a + b for _, a, b in looks]
    fractions = [p / total for p in pairs]
    theta_alpha = THETA_SHARE * alpha
    lower, upper = boundaries(discordant, fractions, theta_alpha)
    decision = A_BETTER if a_only >= upper[0, -1] else B_BETTER if a_only <= lower[0, -1] else UNDECIDED
    t_lo, t_hi = _theta_interval(a_only, discordant, fractions, theta_alpha)
    if decision == UNDECIDED:  # 1/2 is kept exactly when the test does not decide; bisection must not say otherwise
        t_lo, t_hi = min(t_lo, 0.5), max(t_hi, 0.5)
    d_lo, d_hi = _mixture_interval(a_only + b_only, n, alpha - theta_alpha, (DISCORDANCE_PRIOR,) * 2)
    # rate(A) - rate(B) = D (2 theta - 1): linear in each, so its extremes over the two intervals are at corners
    low_side, high_side = 2 * t_lo - 1, 2 * t_hi - 1
    low = low_side * (d_hi if low_side < 0 else d_lo)
    high = high_side * (d_hi if high_side > 0 else d_lo)
    if decision == UNDECIDED:
        low, high = min(low, 0.0), max(high, 0.0)
    spent_so_far = float(spent(fractions[-1], theta_alpha))
    return Assessment(
        n, a_only, b_only, alpha, decision, (a_only - b_only) / n, (low, high), (t_lo, t_hi), int(upper[0, -1]),
        spent_so_far,
    )  # fmt: skip
