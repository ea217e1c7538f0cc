"""The study's twelve findings, each judged on this build's episode files: the study's figures, this build's (with
episode counts), the test, its p-value, the smallest gap it could resolve and a verdict (``by_policy.verdict``), or
'not run' naming what is missing. Each row's figures are taken per trained policy, and the claims (``claims``) are
tested with the policy as the unit when a row has several.

Nothing here is typed in but the study's own figures: every figure of this build is computed from the
evaluation files under results/runs/ that the tables read."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import polars as pl

from ..evaluation import taxonomy
from . import by_policy, claims, stats, tables
from .tables import Row

PURE, G2D, G3D = "Pure Visual", "2D-Spatial-Proj", "Explicit-3D-GT"


@dataclass(frozen=True)
class Finding:
    id: int
    table: str
    claim: str
    study: str  # the study's figures
    rows: tuple[str, ...]  # the table's row labels it compares
    needs: tuple[str, ...]
    judge: Callable[[dict[str, Row]], list[stats.Check]]


def _policies(frame: pl.DataFrame) -> list[pl.DataFrame]:
    return tables.per_policy(frame)


def _sr(rows, label, need="stability") -> claims.Counts:
    return [stats.successes(p) for p in _policies(rows[label].data[need])]


def _lengths(rows, label) -> list[list[float]]:
    return [p.filter(~pl.col("trivial"))["steps"].to_list() for p in _policies(rows[label].data["stability"])]


def _class_count(rows, label, cls) -> claims.Counts:
    """Per policy: (episodes of class ``cls``, classified non-trivial episodes) of its failure run."""
    counts = [taxonomy.counts(p) for p in _policies(rows[label].data["failures"])]
    return [(c[cls], sum(c.values())) for c in counts]


def _failures_of(rows, label, cls) -> claims.Counts:
    """Per policy: (episodes of class ``cls``, failed non-trivial episodes)."""
    counts = [taxonomy.counts(p) for p in _policies(rows[label].data["failures"])]
    return [(c[cls], sum(c.values()) - c["Success"]) for c in counts]


def _peak_returns(rows, label) -> list[list[float]]:
    """Per policy: the sweep's episode returns at its best checkpoint (Table 5.7's 'reward at peak')."""
    sweeps = _policies(rows[label].data["sweep"])
    return [sweep.filter(pl.col("checkpoint") == best["epoch"])["return"].to_list()
            for best, sweep in zip(rows[label].data["best"], sweeps, strict=True)]


def _train_seed_sr(rows, label) -> claims.Counts:
    return _sr(rows, label, "train_seeds")


def _f1(r):
    return [claims.rate_less(PURE, _sr(r, PURE), G2D, _sr(r, G2D)),
            claims.rate_less(G2D, _sr(r, G2D), G3D, _sr(r, G3D))]


def _f2(r):
    return [claims.values_greater(PURE, _lengths(r, PURE), G2D, _lengths(r, G2D), "length", "steps"),
            claims.values_greater(G2D, _lengths(r, G2D), G3D, _lengths(r, G3D), "length", "steps")]


def _f3(r):
    return [claims.rate_less(G3D, _class_count(r, G3D, "Near Miss"), PURE, _class_count(r, PURE, "Near Miss"),
                             "Near Miss share"),
            claims.rate_equal(PURE, _class_count(r, PURE, "No Grasp"), G3D, _class_count(r, G3D, "No Grasp"),
                              "No Grasp share")]


def _f4(r):
    a, e128, e224 = "approx-128", "exact-128", "exact-224"
    return [claims.rate_less(a, _sr(r, a), e128, _sr(r, e128), strict=False),
            claims.rate_less(e128, _sr(r, e128), e224, _sr(r, e224))]


def _f5(r):
    # SPOT where its weights are given, else the offline slot encoder
    slots = "SPOT 14 slots" if r.get("SPOT 14 slots") and r["SPOT 14 slots"].status is None \
        else "slots_ssl 14 slots (offline)"
    return [claims.rate_less("DINO CLS", _sr(r, "DINO CLS"), slots, _sr(r, slots)),
            claims.rate_less("DINO 4x4", _sr(r, "DINO 4x4"), slots, _sr(r, slots)),
            claims.rate_at_most("DINO 14x14 dense", _sr(r, "DINO 14x14 dense"), 0.05)]


def _f6(r):
    st = "Slot Transformer"
    run = "training_time"  # the study's heads: one 30-episode training-time run each
    return [claims.rate_less(other, _sr(r, other, run), st, _sr(r, st, run), strict=False)
            for other in r if other != st]


def _f7(r):
    cat, xat = "Concatenation", "Cross-attention"
    return [claims.rate_less(cat, _train_seed_sr(r, cat), xat, _train_seed_sr(r, xat), "training-seed SR"),
            claims.rate_equal(cat, _sr(r, cat), xat, _sr(r, xat), "held-out SR")]


def _f8(r):
    t5, t20, t40 = "T=5", "T=20", "T=40"
    return [claims.rate_equal(t5, _sr(r, t5), t20, _sr(r, t20)), claims.rate_equal(t5, _sr(r, t5), t40, _sr(r, t40)),
            claims.values_greater(t5, _peak_returns(r, t5), t20, _peak_returns(r, t20), "reward at peak", "reward"),
            claims.values_greater(t20, _peak_returns(r, t20), t40, _peak_returns(r, t40), "reward at peak", "reward")]


def _f9(r):
    dof7, glob, grouped = "7-DoF", "9-DoF global z-score", "9-DoF grouped z-score"
    return [claims.rate_less(glob, _sr(r, glob), dof7, _sr(r, dof7)), claims.rate_at_most(glob, _sr(r, glob), 0.05),
            claims.rate_less(grouped, _sr(r, grouped), dof7, _sr(r, dof7))]


def _f10(r):
    return [claims.rate_less(w, _sr(r, w), "Uniform", _sr(r, "Uniform"), strict=False) for w in r if w != "Uniform"]


def _f11(r):
    native, aligned = "Native (base + hand, no goal)", "Aligned (base + side, 2D goal)"
    return [claims.rate_less(native, _sr(r, native), aligned, _sr(r, aligned))]


def _f12(r):
    aligned = "Aligned (base + side, 2D goal)"
    return [claims.rate_above(aligned, _failures_of(r, aligned, "No Grasp"), 0.5, "No Grasp share of failures")]


FINDINGS = (
    Finding(1, "table5_1", "SR: Pure Visual < 2D < 3D", "31.0 / 55.0 / 71.7 %", (PURE, G2D, G3D), ("stability",), _f1),
    Finding(2, "table5_1", "episode length: Pure Visual > 2D > 3D", "313 / 247 / 182 steps", (PURE, G2D, G3D),
            ("stability",), _f2),
    Finding(3, "table5_2", "Near Miss share falls from Pure Visual to 3D; No Grasp about the same",
            "Near Miss 31.0 / 21.0 / 2.5 %; No Grasp 7.5 / 7.5 / 12.0 %", (PURE, G3D), ("failures",), _f3),
    Finding(4, "table5_3", "SR: approx-128 <= exact-128 < exact-224", "55.0 / 58.7 / 68.7 %",
            ("approx-128", "exact-128", "exact-224"), ("stability",), _f4),
    Finding(5, "table5_4", "slots above DINO CLS and DINO 4x4; dense DINO near zero",
            "SPOT 55.0; CLS 32.6; 4x4 31.7; dense 1.0 % (peak)",
            ("DINO CLS", "DINO 4x4", "DINO 14x14 dense", "slots_ssl 14 slots (offline)"), ("stability",), _f5),
    Finding(6, "table5_5", "Slot Transformer at least as good as the other heads (qualitative)",
            "13.3 against 10.0 / 6.7 / 10.0 % (30 episodes)", (), ("training_time",), _f6),
    Finding(7, "table5_6", "cross-attention fits the training seeds better than concatenation, both equal held out "
            "(so its gap is larger)", "training seeds 60.0 vs 38.6 %; held out 31.0 vs 31.0 %",
            ("Concatenation", "Cross-attention"), ("stability", "train_seeds"), _f7),
    Finding(8, "table5_7", "one training budget: SR does not change with T; reward at peak falls as T grows",
            "SR 6.7 / 6.7 / 6.7 %; reward at peak 70 / 45 / 36", ("T=5", "T=20", "T=40"),
            ("stability", "best", "sweep"), _f8),
    Finding(9, "table5_8", "9-DoF with global z-score fails (gripper stuck closed); grouped below 7-DoF",
            "0.0 / 6.7 / 31.0 %", ("7-DoF", "9-DoF global z-score", "9-DoF grouped z-score"), ("stability",), _f9),
    Finding(10, "table5_9", "every loss weighting at or below uniform",
            "uniform 55.0; time 38.9; U-shaped 34.8; dim-decoupled 49.8 %", (), ("stability",), _f10),
    Finding(11, "table5_10", "StackCube: aligned above native", "native 1.5 %; aligned 5.3 %",
            ("Native (base + hand, no goal)", "Aligned (base + side, 2D goal)"), ("stability",), _f11),
    Finding(12, "table5_11", "StackCube failures are mostly No Grasp", "No Grasp 72.0 %, Near Miss 10.0 %",
            ("Aligned (base + side, 2D goal)",), ("failures",), _f12),
)
BY_ID = {f.id: f for f in FINDINGS}
# the findings a target reports, those its tables cover: the main job's (Tables 5.1-5.2) 1-3, the ablations'
# (5.3-5.9) 4-10, StackCube's (5.10-5.11) 11-12; `all` reports the twelve
SCOPES = {"findings": tuple(BY_ID), "findings_main": (1, 2, 3), "findings_ablations": tuple(range(4, 11)),
          "findings_stackcube": (11, 12)}


def not_run(finding: Finding, rows: dict[str, Row]) -> str | None:
    """Why a finding cannot be judged (a row missing from config, or one that needs weights), or None."""
    missing = [label for label in finding.rows if label not in rows]
    if missing:
        return f"not run: {finding.table} has no row {', '.join(map(repr, missing))}"
    blocked = {label: row.status for label, row in rows.items()
               if row.status and (label in finding.rows or not finding.rows)}
    if blocked:
        return "not run: " + "; ".join(f"{label} {why}" for label, why in blocked.items())
    return None


def judge(finding: Finding, rows: dict[str, Row]) -> dict:
    """One line of the findings table."""
    base = {"Finding": finding.id, "Table": finding.table.replace("table", "").replace("_", "."),
            "Claim": finding.claim, "Study": finding.study}
    reason = not_run(finding, rows)
    if reason:
        return {**base, "This build": None, "Test": None, "p": None, "Resolvable at 80 % power": None,
                "Verdict": reason}
    checks = finding.judge(rows)
    p = [c.p for c in checks if c.directional and c.p is not None]
    resolvable = [c.resolvable for c in checks if c.resolvable]
    return {**base, "This build": "; ".join(c.text for c in checks),
            "Test": "; ".join(f"{c.test} p={c.p:.3g}" if c.p is not None else c.test for c in checks),
            "p": max(p) if p else None, "Resolvable at 80 % power": "; ".join(resolvable) or None,
            "Verdict": verdict_of(checks, rows)}


def verdict_of(checks: list[stats.Check], rows: dict[str, Row]) -> str:
    """The verdict of a finding's checks; 'about the same' and 'at most' claims have an equivalence margin only
    where each row is several policies (tested with the policy as the unit)."""
    replicated = min((r.policies for r in rows.values() if r.status is None), default=1) > 1
    return by_policy.verdict([c.outcome for c in checks], by_policy.MARGIN if replicated else None)
