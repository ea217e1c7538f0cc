"""The study's statistics, below every stage that uses them: `pooled` tests success counts of episodes pooled as
one binomial sample (Fisher's exact test, Wilson intervals), `by_policy` tests rows with the trained policy as the
unit (Welch's t over per-policy rates, equivalence and non-inferiority, the gap a test can resolve)."""
