"""A finding's claims about rows, each row given per policy: with one policy per row, the episode tests of
``ocpipe.stats.pooled`` (Fisher, Mann-Whitney, binomial: episode noise only); with K policies, the tests of
``ocpipe.stats.by_policy``, whose unit is the trained policy, with the smallest gap (or equivalence margin) each
could resolve at 80 % power."""

from __future__ import annotations

import numpy as np

from ..stats import by_policy, pooled
from ..stats.by_policy import PolicyValues

Counts = list[tuple[int, int]]  # (successes, episodes) per policy


def _rate(counts: Counts) -> str:
    if len(counts) == 1:
        return pooled.format_rate(counts[0])
    rates = [k / n for k, n in counts if n]
    k, n = (sum(c) for c in zip(*counts, strict=True))
    return f"{100 * np.mean(rates):.1f} % ± {100 * np.std(rates, ddof=1):.1f} ({len(counts)} policies, {k}/{n})"


def _values(counts: Counts) -> PolicyValues | None:
    """A row's per-policy rates, leaving out policies with nothing to count (a share of failures where a policy
    never failed); None when fewer than 2 are left."""
    kept = [c for c in counts if c[1] > 0]
    return PolicyValues.of_counts(kept) if len(kept) >= 2 else None


def _check(text: str, result: by_policy.Result, unit: str = "rate") -> pooled.Check:
    gap = result.resolvable_gap
    shown = f"{100 * gap:.1f} points" if unit == "rate" else f"{gap:.1f} {unit}"
    if np.isnan(gap):
        shown = "no spread to scale it"
    return pooled.Check(text, result.test, result.p, result.outcome, True, shown)


def _too_few(text: str) -> pooled.Check:
    return pooled.Check(f"{text}: fewer than 2 policies with episodes to count", "Welch t over policies", None,
                       "unresolved")


def rate_less(a: str, ka: Counts, b: str, kb: Counts, what: str = "SR", strict: bool = True) -> pooled.Check:
    """Claim: a's rate below b's (``strict``), or at most b's (non-inferiority within by_policy.MARGIN)."""
    if len(ka) == 1 and len(kb) == 1:
        return pooled.rate_less(a, ka[0], b, kb[0], what, strict)
    text = f"{what} {a} {_rate(ka)} {'<' if strict else '<='} {b} {_rate(kb)}"
    va, vb = _values(ka), _values(kb)
    if va is None or vb is None:
        return _too_few(text)
    return _check(text, by_policy.less(va, vb) if strict else by_policy.at_most(va, vb))


def rate_equal(a: str, ka: Counts, b: str, kb: Counts, what: str = "SR") -> pooled.Check:
    """Claim: the two rates are about the same (equivalence within by_policy.MARGIN)."""
    if len(ka) == 1 and len(kb) == 1:
        return pooled.rate_equal(a, ka[0], b, kb[0], what)
    text = f"{what} {a} {_rate(ka)} ~ {b} {_rate(kb)}"
    va, vb = _values(ka), _values(kb)
    if va is None or vb is None:
        return _too_few(text)
    return _check(text, by_policy.equal(va, vb))


def rate_at_most(a: str, ka: Counts, share: float, what: str = "SR") -> pooled.Check:
    """Claim: a's rate is at most ``share`` (the bound the claim names, e.g. 'near zero')."""
    if len(ka) == 1:
        return pooled.rate_at_most(a, ka[0], share, what)
    text = f"{what} {a} {_rate(ka)} <= {100 * share:.0f} %"
    va = _values(ka)
    return _too_few(text) if va is None else _check(text, by_policy.at_most_share(va, share))


def rate_above(a: str, ka: Counts, share: float, what: str) -> pooled.Check:
    """Claim: a's rate is above ``share`` (e.g. 'mostly')."""
    if len(ka) == 1:
        return pooled.rate_above(a, ka[0], share, what)
    text = f"{what} {a} {_rate(ka)} > {100 * share:.0f} %"
    va = _values(ka)
    return _too_few(text) if va is None else _check(text, by_policy.above_share(va, share))


def values_greater(a: str, va: list[list[float]], b: str, vb: list[list[float]], what: str, unit: str) -> pooled.Check:
    """Claim: a's values (episode lengths, rewards) are larger than b's: per policy, the mean of its values."""
    if len(va) == 1 and len(vb) == 1:
        return pooled.values_greater(a, va[0], b, vb[0], what)
    pa, pb = PolicyValues.of_samples(va), PolicyValues.of_samples(vb)
    ma, mb = pa.values, pb.values
    text = (f"{what} {a} {ma.mean():.1f} ± {ma.std(ddof=1):.1f} ({len(ma)} policies) > "
            f"{b} {mb.mean():.1f} ± {mb.std(ddof=1):.1f} ({len(mb)} policies)")
    if len(ma) < 2 or len(mb) < 2:
        return _too_few(text)
    return _check(text, by_policy.less(pb, pa), unit)
