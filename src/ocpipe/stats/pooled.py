"""Claims about two rows of a table, judged on their episodes: is the claimed order there, and can the episodes
resolve it? Each check gives the figures it compared, the test, its p-value and an outcome:

  holds       the claim holds and is resolved (p < ALPHA)
  not contradicted  an 'equal' or 'at most' claim that the episodes do not resolve against: no evidence for it
              either (one policy per row offers no equivalence test; by_policy's K-policy tests do)
  unresolved  the claimed direction is seen but p >= ALPHA
  tie         neither direction is seen (equal figures)
  opposite    the opposite direction is seen, not resolved
  violated    the opposite direction is resolved, or an 'equal' claim is resolved apart"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl
from scipy import stats

ALPHA = 0.05


@dataclass(frozen=True)
class Check:
    text: str  # what was compared, with its figures
    test: str
    p: float | None
    outcome: str  # holds | unresolved | tie | opposite | violated
    directional: bool = True  # p is the evidence for the claim (an order's, or a test of a bounded claim)
    resolvable: str | None = None  # K policies: the smallest gap (or equivalence margin) resolvable at 80 % power


def successes(episodes: pl.DataFrame) -> tuple[int, int]:
    """(non-trivial successes, non-trivial episodes) over every run in ``episodes``."""
    kept = episodes.filter(~pl.col("trivial"))
    return int(kept["success"].sum()), len(kept)


def success_rate(episodes: pl.DataFrame) -> float:
    """Share of episodes that succeeded non-trivially; trivial successes count in neither numerator nor total."""
    k, n = successes(episodes)
    return k / n if n else float("nan")


def interval(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The Wilson score interval of a success rate of k in n: the spread a single run's SR can claim."""
    if n == 0:
        return float("nan"), float("nan")
    ci = stats.binomtest(k, n).proportion_ci(confidence, method="wilson")
    return float(ci.low), float(ci.high)


def t_half_width(values, confidence: float = 0.95, sd: float | None = None) -> float:
    """Half the width of the t interval of the mean of ``values`` (independent policies' SRs), at their sample SD or
    the given ``sd``: nan for fewer than 2."""
    v = np.asarray(values, float)
    if len(v) < 2:
        return float("nan")
    sd = v.std(ddof=1) if sd is None else sd
    return float(stats.t.ppf((1 + confidence) / 2, len(v) - 1) * sd / np.sqrt(len(v)))


def format_rate(kn: tuple[int, int]) -> str:
    k, n = kn
    return f"{k}/{n} ({100 * k / n:.1f} %)" if n else f"{k}/0"


def fisher(a: tuple[int, int], b: tuple[int, int], alternative: str) -> float:
    """Fisher's exact test on two (successes, episodes) counts; ``alternative`` as scipy's ('greater': a's rate
    above b's)."""
    table = [[a[0], a[1] - a[0]], [b[0], b[1] - b[0]]]
    return float(stats.fisher_exact(table, alternative=alternative).pvalue)


def _order(p_claimed: float, p_opposite: float, seen: float, strict: bool) -> str:
    """``seen``: > 0 when the figures lean the claimed way, < 0 the other way, 0 when equal."""
    if p_opposite < ALPHA:
        return "violated"
    if not strict:
        return "not contradicted"
    if p_claimed < ALPHA:
        return "holds"
    return "unresolved" if seen > 0 else "tie" if seen == 0 else "opposite"


def rate_less(a: str, ka: tuple[int, int], b: str, kb: tuple[int, int], what: str = "SR",
              strict: bool = True) -> Check:
    """Claim: ``a``'s rate < ``b``'s (``strict``), or at most ``b``'s. Fisher's exact test, one-sided."""
    if not ka[1] or not kb[1]:
        return Check(f"{what} {a} vs {b}: no episodes", "Fisher exact, one-sided", None, "unresolved")
    p_less, p_greater = fisher(ka, kb, "less"), fisher(ka, kb, "greater")
    seen = kb[0] / kb[1] - ka[0] / ka[1]
    sign = "<" if strict else "<="
    return Check(f"{what} {a} {format_rate(ka)} {sign} {b} {format_rate(kb)}", "Fisher exact, one-sided",
                 p_less if strict else p_greater, _order(p_less, p_greater, seen, strict), strict)


def rate_equal(a: str, ka: tuple[int, int], b: str, kb: tuple[int, int], what: str = "SR") -> Check:
    """Claim: the two rates are about the same. Violated when Fisher's two-sided test resolves them apart."""
    if not ka[1] or not kb[1]:
        return Check(f"{what} {a} vs {b}: no episodes", "Fisher exact, two-sided", None, "unresolved", False)
    p = fisher(ka, kb, "two-sided")
    return Check(f"{what} {a} {format_rate(ka)} ~ {b} {format_rate(kb)}", "Fisher exact, two-sided", p,
                 "violated" if p < ALPHA else "not contradicted", False)


def rate_at_most(a: str, ka: tuple[int, int], share: float, what: str = "SR") -> Check:
    """Claim: ``a``'s rate is at most ``share`` (e.g. 'near zero'). Violated when a one-sided binomial test
    resolves it above."""
    if not ka[1]:
        return Check(f"{what} {a}: no episodes", "binomial, one-sided", None, "unresolved", False)
    p = float(stats.binomtest(ka[0], ka[1], share, alternative="greater").pvalue)
    return Check(f"{what} {a} {format_rate(ka)} <= {100 * share:.0f} %", "binomial, one-sided", p,
                 "violated" if p < ALPHA else "not contradicted", False)


def rate_above(a: str, ka: tuple[int, int], share: float, what: str) -> Check:
    """Claim: ``a``'s rate is above ``share`` (e.g. 'most'). One-sided binomial test."""
    if not ka[1]:
        return Check(f"{what} {a}: no episodes", "binomial, one-sided", None, "unresolved")
    k, n = ka
    p_greater = float(stats.binomtest(k, n, share, alternative="greater").pvalue)
    p_less = float(stats.binomtest(k, n, share, alternative="less").pvalue)
    return Check(f"{what} {a} {format_rate(ka)} > {100 * share:.0f} %", "binomial, one-sided", p_greater,
                 _order(p_greater, p_less, k / n - share, True))


def values_greater(a: str, va, b: str, vb, what: str) -> Check:
    """Claim: ``a``'s values are larger than ``b``'s (e.g. episode lengths). Mann-Whitney U, one-sided."""
    va, vb = np.asarray(va, float), np.asarray(vb, float)
    if not len(va) or not len(vb):
        return Check(f"{what} {a} vs {b}: no episodes", "Mann-Whitney U, one-sided", None, "unresolved")
    p_greater = float(stats.mannwhitneyu(va, vb, alternative="greater").pvalue)
    p_less = float(stats.mannwhitneyu(va, vb, alternative="less").pvalue)
    return Check(f"{what} {a} {va.mean():.1f} (n={len(va)}) > {b} {vb.mean():.1f} (n={len(vb)})",
                 "Mann-Whitney U, one-sided", p_greater, _order(p_greater, p_less, va.mean() - vb.mean(), True))
