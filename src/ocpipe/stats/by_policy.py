"""Claims about rows judged with the trained policy as the unit of evidence.

A row of a table is K policies trained independently from one recipe, each evaluated on its own block of episodes.
Two sources of spread act on a row's success rate: the episodes a policy meets (binomial) and the training run
itself (initialisation, batch order, the float kernels of the machine), which moved one recipe's Pure Visual row
from 25 to 12 of 119 between two builds. Pooling a row's episodes and testing them as one binomial sample (Fisher's
exact test) sees only the first, so it calls rows different that are not (simulate_false_positives shows how often).

Here each policy contributes one number (its success rate, or a share, or a mean), and rows are compared with
Welch's t-test on those K numbers: its variance is the spread between policies, which holds both sources, and it
needs no equal variances. Where a row's K rates happen to agree more closely than its episodes alone allow, its
variance is floored at the binomial variance of one policy's rate, p (1 - p) mean(1 / n) at the two rows' pooled
rate p (half a success added, so that rows at 0 % keep a floor): the episode noise every policy carries, which a small
K can hide (five policies at 0 of 40 would otherwise be 'resolved' below five at 1 of 40 with p = 0).
simulate_false_positives measures how close to nominal the test stays where rates are far from normal (docs/study.md
gives the figures).

'About the same' claims are tested for equivalence (two one-sided tests, TOST) within a margin, and 'at most'
claims for non-inferiority with that margin: such a claim counts only when its test resolves it, never merely
because no difference was found."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from .pooled import ALPHA

POWER = 0.8
MARGIN = 0.10  # of a rate or share, unless a finding names another


@dataclass(frozen=True)
class PolicyValues:
    """One row's per-policy figures: ``values`` (a rate or share per policy) and ``episodes`` (how many episodes
    each value is of; the binomial floor uses them, None for values that are not rates)."""

    values: np.ndarray
    episodes: np.ndarray | None = None
    # values that are means over a policy's episodes (lengths, returns): the variance of one policy's mean from its
    # episodes alone, the floor of the between-policy variance as the binomial one is for rates
    noise: float | None = None

    @classmethod
    def of_counts(cls, counts) -> PolicyValues:
        """From (successes, episodes) per policy."""
        k, n = np.asarray(counts, float).reshape(-1, 2).T
        if (n <= 0).any():
            raise ValueError(f"a policy with no episodes among {counts}")
        return cls(k / n, n)

    @classmethod
    def of_samples(cls, samples) -> PolicyValues:
        """From each policy's episode values (lengths, returns): its mean, with the episode noise of a mean."""
        kept = [np.asarray(s, float) for s in samples if len(s)]
        noise = [s.var(ddof=1) / len(s) for s in kept if len(s) > 1]
        return cls(np.array([s.mean() for s in kept]), noise=float(np.mean(noise)) if noise else None)

    @property
    def mean(self) -> float:
        return float(self.values.mean())

    @property
    def policies(self) -> int:
        return len(self.values)

    def variance(self, rate: float | None = None) -> float:
        """The between-policy variance of one policy's value, floored at the episode noise of a policy at ``rate``
        (module docstring; the two rows' pooled rate, as under 'no difference')."""
        sample = float(self.values.var(ddof=1)) if self.policies > 1 else 0.0
        if self.episodes is not None and rate is not None:
            return max(sample, rate * (1 - rate) * float((1 / self.episodes).mean()))
        return sample if self.noise is None else max(sample, self.noise)


@dataclass(frozen=True)
class Welch:
    difference: float  # mean of a minus mean of b
    se: float
    df: float

    @classmethod
    def of(cls, a: PolicyValues, b: PolicyValues) -> Welch:
        if a.policies < 2 or b.policies < 2:
            raise ValueError(f"rows of {a.policies} and {b.policies} policies: the spread between policies needs "
                             "at least 2 per row (config `replicates`, `table_replicates`)")
        pooled = None
        if a.episodes is not None and b.episodes is not None:
            # half a success added: rows that never (or always) succeed still carry episode noise, so a gap between
            # two rows at 0 of 40 per policy is not 'resolvable' at 0 points
            pooled = (float((a.values * a.episodes).sum() + (b.values * b.episodes).sum()) + 0.5) / float(
                a.episodes.sum() + b.episodes.sum() + 1)
        va, vb = a.variance(pooled) / a.policies, b.variance(pooled) / b.policies
        se = float(np.sqrt(va + vb))
        df = (va + vb) ** 2 / (va**2 / (a.policies - 1) + vb**2 / (b.policies - 1)) if se > 0 else 1.0
        return cls(a.mean - b.mean, se, float(df))

    def p_below(self, shift: float = 0.0) -> float:
        """One-sided p of 'difference < shift'."""
        if self.se == 0:
            return 0.0 if self.difference < shift else 1.0
        return float(stats.t.cdf((self.difference - shift) / self.se, self.df))

    def p_above(self, shift: float = 0.0) -> float:
        """One-sided p of 'difference > shift'."""
        if self.se == 0:
            return 0.0 if self.difference > shift else 1.0
        return float(stats.t.sf((self.difference - shift) / self.se, self.df))

    def resolvable_gap(self, alpha: float = ALPHA, power: float = POWER) -> float:
        """The smallest true difference a one-sided test at ``alpha`` finds with probability ``power``, at this
        spread and these policy counts (nan where the values have no spread at all to scale it)."""
        if self.se == 0:
            return float("nan")
        return float((stats.t.ppf(1 - alpha, self.df) + stats.t.ppf(power, self.df)) * self.se)

    def resolvable_margin(self, alpha: float = ALPHA, power: float = POWER) -> float:
        """The narrowest margin within which TOST shows two rows of truly equal means equivalent with probability
        ``power``, at this spread and these policy counts."""
        if self.se == 0:
            return float("nan")
        return float((stats.t.ppf(1 - alpha, self.df) + stats.t.ppf((1 + power) / 2, self.df)) * self.se)


@dataclass(frozen=True)
class Result:
    test: str
    p: float  # of the claim (the smaller, the stronger the evidence for it)
    outcome: str  # holds | unresolved | tie | opposite | violated | not contradicted
    # at 80 % power: the smallest difference an order or 'at most' test resolves; for 'about the same', the
    # narrowest margin its equivalence test could show
    resolvable_gap: float


def _order(p: float, p_opposite: float, leaning: float, alpha: float) -> str:
    """An order claim's outcome; ``leaning``: > 0 when the figures lean the claimed way, < 0 the other, 0 level."""
    if p_opposite < alpha:
        return "violated"
    if p < alpha:
        return "holds"
    return "unresolved" if leaning > 0 else "tie" if leaning == 0 else "opposite"


def _bounded(p: float, p_violated: float, alpha: float) -> str:
    """An 'at most' claim's outcome: it needs its own test resolved, and fails where the opposite is resolved."""
    return "violated" if p_violated < alpha else "holds" if p < alpha else "not contradicted"


def less(a: PolicyValues, b: PolicyValues, alpha: float = ALPHA) -> Result:
    """Claim: a's mean < b's. Holds when resolved; violated when the opposite is resolved."""
    w = Welch.of(a, b)
    p = w.p_below()
    outcome = _order(p, w.p_above(), -w.difference, alpha)
    return Result("Welch t over policies, one-sided", p, outcome, w.resolvable_gap(alpha))


def at_most(a: PolicyValues, b: PolicyValues, margin: float = MARGIN, alpha: float = ALPHA) -> Result:
    """Claim: a's mean is at most b's. Holds when non-inferiority resolves a < b + margin; violated when a > b is
    resolved; else not contradicted."""
    w = Welch.of(a, b)
    p = w.p_below(margin)
    outcome = _bounded(p, w.p_above(), alpha)
    return Result(f"Welch t over policies, non-inferiority margin {margin:g}", p, outcome, w.resolvable_gap(alpha))


def equal(a: PolicyValues, b: PolicyValues, margin: float = MARGIN, alpha: float = ALPHA) -> Result:
    """Claim: the means are about the same. Holds when TOST resolves |a - b| < margin; violated when a one-sided
    test resolves them more than the margin apart (either way); else not contradicted."""
    w = Welch.of(a, b)
    p = max(w.p_above(-margin), w.p_below(margin))
    apart = min(w.p_above(margin), w.p_below(-margin)) < alpha / 2
    outcome = "violated" if apart else "holds" if p < alpha else "not contradicted"
    return Result(f"TOST over policies, margin {margin:g}", p, outcome, w.resolvable_margin(alpha))


def _against(a: PolicyValues, share: float) -> Welch:
    """One row's mean against a fixed ``share``, as a one-sample t over its policies (floored at the binomial noise
    of a policy at that share, the rate the claim's boundary puts it at)."""
    if a.policies < 2:
        raise ValueError(f"a row of {a.policies} policy: the spread between policies needs at least 2 (config "
                         "`replicates`, `table_replicates`)")
    return Welch(a.mean - share, float(np.sqrt(a.variance(share) / a.policies)), float(a.policies - 1))


def at_most_share(a: PolicyValues, share: float, alpha: float = ALPHA) -> Result:
    """Claim: a's mean is at most ``share`` (e.g. 'near zero': 5 %, the bound the claim names). Holds when resolved
    below it; violated when resolved above; else not contradicted."""
    w = _against(a, share)
    p = w.p_below()
    outcome = _bounded(p, w.p_above(), alpha)
    return Result(f"t over policies against {share:g}, one-sided", p, outcome, w.resolvable_gap(alpha))


def above_share(a: PolicyValues, share: float, alpha: float = ALPHA) -> Result:
    """Claim: a's mean is above ``share`` (e.g. 'mostly': 50 %). Holds when resolved; violated when resolved below."""
    w = _against(a, share)
    p = w.p_above()
    outcome = _order(p, w.p_below(), w.difference, alpha)
    return Result(f"t over policies against {share:g}, one-sided", p, outcome, w.resolvable_gap(alpha))


def verdict(outcomes: list[str], margin: float | None = MARGIN) -> str:
    """A finding's verdict from its checks' outcomes, worst first; ``margin`` None: rows of one policy, whose 'about
    the same' and 'at most' claims no equivalence test could show."""
    found = set(outcomes)
    unshown = (f"not contradicted, could not resolve ±{100 * margin:.0f} points" if margin is not None
               else "not contradicted, one policy per row: no equivalence test")
    for outcome, says in (("violated", "not reproduced"), ("opposite", "opposite direction, not resolved"),
                          ("tie", "no difference seen, not resolved"), ("unresolved", "same direction, not resolved"),
                          ("not contradicted", unshown)):
        if outcome in found:
            return says
    return "reproduced"


def simulate_rows(rate: float, between_sd: float, policies: int, episodes: int, rows: int,
                  rng: np.random.Generator) -> np.ndarray:
    """Success counts (rows, policies) of rows whose policies' true rates spread by ``between_sd`` around ``rate``
    (clipped to [0, 1]), each policy meeting ``episodes`` episodes."""
    true = np.clip(rng.normal(rate, between_sd, (rows, policies)), 0, 1)
    return rng.binomial(episodes, true)


def simulate_false_positives(rate: float, between_sd: float, policies: int, episodes: int, sims: int,
                             seed: int = 0) -> dict[str, float]:
    """How often two rows of equal mean are called different at ALPHA (one-sided, a < b): by Welch's test over
    policies, and by Fisher's exact test on the pooled episodes."""
    rng = np.random.default_rng(seed)
    a, b = (simulate_rows(rate, between_sd, policies, episodes, sims, rng) for _ in range(2))
    n = np.full(policies, episodes)
    welch = [less(PolicyValues.of_counts(np.c_[x, n]), PolicyValues.of_counts(np.c_[y, n])).p < ALPHA
             for x, y in zip(a, b)]
    total = policies * episodes
    fisher = [stats.fisher_exact([[x.sum(), total - x.sum()], [y.sum(), total - y.sum()]], "less").pvalue < ALPHA
              for x, y in zip(a, b)]
    return {"welch": float(np.mean(welch)), "fisher": float(np.mean(fisher))}
