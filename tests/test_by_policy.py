"""Tests with the trained policy as the unit (ocpipe.stats.by_policy): each verdict on synthetic rows, and the false
positive rates of the order and equivalence tests, simulated at the default K and episode budget."""

import numpy as np
import pytest

from ocpipe.stats import by_policy as B

K, EPISODES, SIMS = 5, 40, 2000
# the Monte Carlo error of a rate of 0.05 estimated from SIMS draws: a test at nominal passes 3 SE above it
ALLOWED = B.ALPHA + 3 * np.sqrt(B.ALPHA * (1 - B.ALPHA) / SIMS)


def row(*successes, episodes=EPISODES):
    return B.PolicyValues.of_counts([(k, episodes) for k in successes])


def test_an_order_holds_only_when_the_policies_resolve_it():
    assert B.less(row(8, 10, 6, 9, 7), row(20, 24, 18, 22, 21)).outcome == "holds"
    assert B.less(row(8, 16, 6, 20, 7), row(12, 24, 5, 19, 9)).outcome == "unresolved"  # 11.4 vs 13.8 of 40
    assert B.less(row(12, 24, 5, 19, 9), row(8, 16, 6, 20, 7)).outcome == "opposite"
    assert B.less(row(0, 0, 0), row(0, 0, 0)).outcome == "tie"
    assert B.less(row(20, 24, 18, 22, 21), row(8, 10, 6, 9, 7)).outcome == "violated"


def test_rows_that_agree_closely_keep_their_episode_noise():
    # five policies each at 0/40 against five each at 1/40: no spread between policies, so Welch's t alone would
    # resolve 0 % below 2.5 % with p = 0; floored at the binomial variance of a policy at the pooled rate (5.5 of
    # 401, half a success added), the test is what 400 episodes can say
    a, b = row(0, 0, 0, 0, 0), row(1, 1, 1, 1, 1)
    w = B.Welch.of(a, b)
    p = 5.5 / 401
    assert w.se == pytest.approx(np.sqrt(2 * p * (1 - p) / 40 / 5), rel=1e-12)  # derived: a few float64 ops
    assert 0.01 < B.less(a, b).p < B.ALPHA
    # rows that never succeed still carry episode noise: a gap between them is not resolvable at 0 points
    none = row(0, 0, 0, 0, 0)
    assert B.less(none, none).outcome == "tie" and B.less(none, none).resolvable_gap > 0.005  # ~1 point


def test_means_of_episodes_keep_their_episode_noise():
    # five policies whose mean episode lengths happen to agree to 0.1 step, each mean of 40 lengths spread by ~30
    # steps: the spread of the five means alone would resolve a 1-step gap; floored at the variance of one
    # policy's mean from its episodes (~30^2 / 40), it cannot
    rng = np.random.default_rng(0)
    samples = [rng.normal(0, 30, EPISODES) for _ in range(2 * K)]
    a = B.PolicyValues.of_samples([s - s.mean() + 120 + 0.1 * i for i, s in enumerate(samples[:K])])
    b = B.PolicyValues.of_samples([s - s.mean() + 121 + 0.1 * i for i, s in enumerate(samples[K:])])
    assert B.less(B.PolicyValues(a.values), B.PolicyValues(b.values)).outcome == "holds"  # without the floor
    floored = B.less(a, b)
    assert floored.outcome == "unresolved" and floored.resolvable_gap > 5  # se ~ sqrt(2 * 30^2 / 40 / 5) = 3 steps
    noise = np.mean([s.var(ddof=1) / EPISODES for s in samples[:K]])
    assert a.noise == pytest.approx(noise, rel=1e-12)  # derived: a mean of five float64 variances
    # a policy without episodes is left out, and one episode has no spread to floor with
    assert B.PolicyValues.of_samples([[1.0], [], [3.0]]).noise is None
    assert B.PolicyValues.of_samples([[1.0], [], [3.0]]).policies == 2


def test_equal_and_at_most_claims_hold_only_when_their_test_resolves_them():
    same = row(20, 21, 19, 20, 20), row(20, 19, 21, 20, 20)
    assert B.equal(*same).outcome == "holds"  # 50 % against 50 %, tightly: within 10 points, resolved
    assert B.equal(row(10, 30, 15, 25, 20), row(12, 28, 16, 24, 22)).outcome == "not contradicted"  # too spread
    assert B.equal(row(8, 10, 6, 9, 7), row(20, 24, 18, 22, 21)).outcome == "violated"  # 20 % against 53 %
    # resolved apart, but by less than the margin (50 % against 53.5 % over 400 episodes a policy): still about the
    # same
    close = row(200, 201, 199, 200, 200, episodes=400), row(214, 215, 213, 214, 214, episodes=400)
    assert B.less(*close).outcome == "holds" and B.equal(*close).outcome == "holds"
    assert B.at_most(*same).outcome == "holds"
    assert B.at_most(row(10, 30, 15, 25, 20), row(12, 28, 16, 24, 22)).outcome == "not contradicted"
    assert B.at_most(row(20, 24, 18, 22, 21), row(8, 10, 6, 9, 7)).outcome == "violated"


def test_claims_against_a_named_share_hold_only_when_resolved():
    assert B.at_most_share(row(0, 1, 0, 0, 1), 0.05).outcome == "holds"  # 1 % of 200, five policies: near zero
    assert B.at_most_share(row(1, 3, 2, 4, 2), 0.05).outcome == "not contradicted"  # 6 %: cannot tell
    assert B.at_most_share(row(10, 14, 12, 9, 11), 0.05).outcome == "violated"  # 28 %
    assert B.above_share(row(30, 28, 32, 29, 31), 0.5).outcome == "holds"  # 75 %
    assert B.above_share(row(21, 23, 19, 22, 20), 0.5).outcome == "unresolved"  # 52.5 %
    assert B.above_share(row(10, 12, 8, 11, 9), 0.5).outcome == "violated"  # 25 %
    with pytest.raises(ValueError, match="at least 2"):
        B.above_share(row(30), 0.5)


@pytest.mark.parametrize("between_sd", [0.05, 0.10])
def test_a_row_at_the_named_share_is_called_above_it_at_most_at_the_nominal_rate(between_sd):
    rng = np.random.default_rng(3)
    n = np.full(K, EPISODES)
    at = B.simulate_rows(0.5, between_sd, K, EPISODES, SIMS, rng)
    held = np.mean([B.above_share(B.PolicyValues.of_counts(np.c_[x, n]), 0.5).outcome == "holds" for x in at])
    assert held <= ALLOWED


def test_verdicts_combine_outcomes_worst_first():
    assert B.verdict(["holds", "holds"]) == "reproduced"
    assert B.verdict(["holds", "not contradicted"]) == "not contradicted, could not resolve ±10 points"
    assert B.verdict(["not contradicted", "unresolved"]) == "same direction, not resolved"
    assert B.verdict(["unresolved", "opposite"]) == "opposite direction, not resolved"
    assert B.verdict(["holds", "violated"]) == "not reproduced"


def test_one_policy_per_row_cannot_be_judged():
    with pytest.raises(ValueError, match="at least 2 per row"):
        B.less(row(10), row(20, 21))


def test_the_resolvable_gap_shrinks_with_more_policies():
    spread = [6, 14, 9, 12, 8, 11, 7, 13, 10, 10]
    few, many = (B.Welch.of(row(*spread[:k]), row(*[s + 4 for s in spread[:k]])) for k in (3, 10))
    assert many.resolvable_gap() < few.resolvable_gap()
    # at 80 % power the gap exceeds the one-sided critical difference
    assert few.resolvable_gap() > few.se * 2.0


@pytest.mark.parametrize("rate", [0.1, 0.3, 0.5])
@pytest.mark.parametrize("between_sd", [0.05, 0.10])
def test_the_order_test_calls_equal_rows_different_at_most_at_its_nominal_rate(rate, between_sd):
    rates = B.simulate_false_positives(rate, between_sd, K, EPISODES, SIMS, seed=1)
    assert rates["welch"] <= ALLOWED, rates
    # and what the pooled-episode test it replaces does on the same rows
    if between_sd == 0.10:
        assert rates["fisher"] > ALLOWED, rates


@pytest.mark.parametrize("between_sd", [0.05, 0.10])
def test_the_equivalence_test_reproduces_a_gap_of_the_margin_at_most_at_its_nominal_rate(between_sd):
    rng = np.random.default_rng(2)
    a = B.simulate_rows(0.5, between_sd, K, EPISODES, SIMS, rng)
    b = B.simulate_rows(0.5 + B.MARGIN, between_sd, K, EPISODES, SIMS, rng)
    n = np.full(K, EPISODES)
    held = np.mean([B.equal(B.PolicyValues.of_counts(np.c_[x, n]), B.PolicyValues.of_counts(np.c_[y, n])).outcome
                    == "holds" for x, y in zip(a, b)])
    assert held <= ALLOWED
