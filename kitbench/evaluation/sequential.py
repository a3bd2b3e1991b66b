"""An anytime-valid paired comparison of two success rates on the same seeds (`kitbench race`): it may be looked
at after every block of seeds and stopped as soon as it decides, with its error rate still at most alpha.

The test is McNemar's, made sequential. Of the seeds scored so far, the discordant ones (one policy succeeded,
the other failed) carry the difference: under "no difference" each favours A with probability 1/2 whatever the
seeds' difficulty, so the number favouring A is Binomial(discordant, 1/2). Against it stands Robbins' mixture
likelihood ratio (Robbins 1970, "Statistical methods related to the law of the iterated logarithm"; the
beta-binomial mixture of Howard, Ramdas, McAuliffe and Sekhon 2021, "Time-uniform, nonparametric, nonasymptotic
confidence sequences", Ann. Statist. 49(2):1055-1080):

    M_n(theta) = integral of prod_i q^x_i (1 - q)^(1 - x_i) dBeta(q; a, a)  /  prod_i theta^x_i (1 - theta)^(1 - x_i)
               = B(a + s, a + n - s) / B(a, a) / (theta^s (1 - theta)^(n - s))

for s of n discordant seeds favouring A. Under theta it is a nonnegative martingale with mean 1 (the concordant
seeds multiply it by 1), so by Ville's inequality it ever reaches 1/alpha with probability at most alpha, at
whatever looks and whatever the stopping rule. The test decides when M_n(1/2) >= 1/alpha_theta; the direction is
the side s - n/2 is on, and a decision for the wrong side also has probability at most alpha_theta (the mixture
over the wrong half of the prior is a supermartingale when the truth is on the other side).

{theta : M_n(theta) < 1/alpha_theta} is a confidence sequence for theta, the chance that a discordant seed favours A,
valid at every n at once; the test decides exactly when it leaves out 1/2. The success difference is
rate(A) - rate(B) = D (2 theta - 1), D the chance that a seed is discordant, which gets a confidence sequence of
its own from the same mixture over all the seeds (a Beta(1/2, 1/2) prior, as its value is anywhere in [0, 1]).
The two together hold with probability at least 1 - alpha by splitting alpha: `THETA_SHARE` of it to theta (the
decision), the rest to D, so the interval of the difference leaves out 0 exactly when the test decides.

The prior Beta(a, a) on theta decides which differences are found soonest: a small `a` puts its mass near 0 and 1,
where theta sits when one policy rarely wins a seed the other loses (the same seed is hard for both), a large one
near 1/2, where it sits for small differences between independent outcomes. The uniform prior (a = 1) needed
nearly the fewest seeds over the simulated cells at a 15-point difference (a mean median of 96.0, against 95.3 for
a = 1/2) with more power (88.8% against 87.2%; `bench/sequential_sim.py --priors`, docs/evaluation.md)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import brentq  # type: ignore[import-untyped]
from scipy.special import betaln  # type: ignore[import-untyped]

PRIOR = 1.0  # Beta(a, a) on theta, uniform; see the module docstring
DISCORDANCE_PRIOR = 0.5  # Beta(1/2, 1/2) on D
THETA_SHARE = 0.9  # the share of alpha the decision gets; the rest bounds D for the interval of the difference
A_BETTER, B_BETTER, UNDECIDED = "A better", "B better", "no difference detected"


def log_evidence(wins_a, discordant, prior: float = PRIOR, theta=0.5):
    """log M_n(theta): the log mixture likelihood ratio of `wins_a` of `discordant` seeds favouring A (numpy
    arrays of counts broadcast; floats out)."""
    s = np.asarray(wins_a, dtype=np.float64)
    n = np.asarray(discordant, dtype=np.float64)
    theta = np.asarray(theta, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        null = np.where(s > 0, s * np.log(theta), 0.0) + np.where(n - s > 0, (n - s) * np.log1p(-theta), 0.0)
    return betaln(prior + s, prior + n - s) - betaln(prior, prior) - null


def decides(wins_a, discordant, alpha: float, prior: float = PRIOR):
    """Whether the test decides at this look: M_n(1/2) >= 1 / (THETA_SHARE alpha) (vectorised as `log_evidence`)."""
    return log_evidence(wins_a, discordant, prior) >= -math.log(THETA_SHARE * alpha)


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


@dataclass(frozen=True)
class Assessment:
    """Where the comparison stands after `pairs` seeds scored by both: `a_only` seeds only A succeeded on,
    `b_only` only B. `difference` is rate(A) - rate(B), `interval` its anytime-valid 1 - alpha interval;
    `theta_interval` the chance a discordant seed favours A; `evidence` M_n(1/2), decided at 1/`threshold`."""

    pairs: int
    a_only: int
    b_only: int
    alpha: float
    decision: str
    difference: float
    interval: tuple[float, float]
    theta_interval: tuple[float, float]
    evidence: float
    threshold: float

    @property
    def decided(self) -> bool:
        return self.decision != UNDECIDED

    def to_dict(self) -> dict:
        out = asdict(self)
        out["interval"], out["theta_interval"] = list(self.interval), list(self.theta_interval)
        return out


def assess(pairs: int, a_only: int, b_only: int, alpha: float, prior: float = PRIOR) -> Assessment:
    """The test at one look (valid at every look, for any rule that chooses when to stop)."""
    if not 0 <= a_only + b_only <= pairs:
        raise ValueError(f"{a_only} + {b_only} discordant seeds of {pairs}")
    discordant = a_only + b_only
    theta_alpha = THETA_SHARE * alpha
    evidence = float(np.exp(log_evidence(a_only, discordant, prior)))
    decision = UNDECIDED
    if bool(decides(a_only, discordant, alpha, prior)):
        decision = A_BETTER if a_only > b_only else B_BETTER
    t_lo, t_hi = _mixture_interval(a_only, discordant, theta_alpha, (prior, prior))
    d_lo, d_hi = _mixture_interval(discordant, pairs, alpha - theta_alpha, (DISCORDANCE_PRIOR,) * 2)
    # rate(A) - rate(B) = D (2 theta - 1): linear in each, so its extremes over the two intervals are at corners
    low_side, high_side = 2 * t_lo - 1, 2 * t_hi - 1
    lower = low_side * (d_hi if low_side < 0 else d_lo)
    upper = high_side * (d_hi if high_side > 0 else d_lo)
    if decision == UNDECIDED:  # the interval holds 0 then (theta's holds 1/2); rounding must not say otherwise
        lower, upper = min(lower, 0.0), max(upper, 0.0)
    difference = (a_only - b_only) / pairs if pairs else 0.0
    return Assessment(
        pairs, a_only, b_only, alpha, decision, difference, (lower, upper), (t_lo, t_hi), evidence, 1 / theta_alpha
    )
