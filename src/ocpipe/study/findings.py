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

from ..config.errors import ConfigError
from ..evaluation import taxonomy
from ..stats import by_policy, pooled
from . import claims, conditions, registry, tables
from .inputs import BEST, FAILURES, STABILITY, SWEEP, TRAIN_SEEDS, TRAINING_TIME, Input
from .registry import SPATIAL_FIGURES_TABLE, TABLES
from .tables import Row

# the experiments the findings compare: a finding names rows by the experiment they run, so a table's row labels
# (config `tables`, free text) can be renamed without a word to the findings
PURE, G2D, G3D = "pure_visual", "goal2d", "goal3d"
STACK_NATIVE, STACK_ALIGNED = "stack_native", "stack_aligned"


@dataclass(frozen=True)
class Finding:
    id: int
    table: str
    claim: str
    study: str  # the study's figures
    rows: tuple[str, ...]  # the experiments of the table's rows it compares (every row where empty)
    needs: tuple[Input, ...]
    judge: Callable[[dict[str, Row]], list[pooled.Check]]  # rows by experiment -> the claims' checks
    requires: tuple[str, ...] = ()  # where ``rows`` is every row: the experiment the others are compared with

    @property
    def compared(self) -> tuple[str, ...]:
        """The experiments the table must hold for this finding."""
        return self.rows or self.requires


def _policies(frame: pl.DataFrame) -> list[pl.DataFrame]:
    return tables.per_policy(frame)


# each accessor gives a row's label (how the checks name it) and its figures per policy
def _sr(rows, exp, need: Input = STABILITY) -> tuple[str, claims.Counts]:
    return rows[exp].label, [pooled.successes(p) for p in _policies(rows[exp].data[need])]


def _lengths(rows, exp) -> tuple[str, list[list[float]]]:
    return rows[exp].label, [p.filter(~pl.col("trivial"))["steps"].to_list()
                             for p in _policies(rows[exp].data[STABILITY])]


def _class_count(rows, exp, cls) -> tuple[str, claims.Counts]:
    """Per policy: (episodes of class ``cls``, classified non-trivial episodes) of its failure run."""
    counts = [taxonomy.counts(p) for p in _policies(rows[exp].data[FAILURES])]
    return rows[exp].label, [(c[cls], sum(c.values())) for c in counts]


def _failures_of(rows, exp, cls) -> tuple[str, claims.Counts]:
    """Per policy: (episodes of class ``cls``, failed non-trivial episodes)."""
    counts = [taxonomy.counts(p) for p in _policies(rows[exp].data[FAILURES])]
    return rows[exp].label, [(c[cls], sum(c.values()) - c["Success"]) for c in counts]


def _peak_returns(rows, exp) -> tuple[str, list[list[float]]]:
    """Per policy: the sweep's episode returns at its best checkpoint (Table 5.7's 'reward at peak')."""
    sweeps = _policies(rows[exp].data[SWEEP])
    return rows[exp].label, [sweep.filter(pl.col("checkpoint") == best["epoch"])["return"].to_list()
                             for best, sweep in zip(rows[exp].data[BEST], sweeps, strict=True)]


def _f1(r):
    return [claims.rate_less(*_sr(r, PURE), *_sr(r, G2D)), claims.rate_less(*_sr(r, G2D), *_sr(r, G3D))]


def _f2(r):
    return [claims.values_greater(*_lengths(r, PURE), *_lengths(r, G2D), "length", "steps"),
            claims.values_greater(*_lengths(r, G2D), *_lengths(r, G3D), "length", "steps")]


def _f3(r):
    return [claims.rate_less(*_class_count(r, G3D, "Near Miss"), *_class_count(r, PURE, "Near Miss"),
                             "Near Miss share"),
            claims.rate_equal(*_class_count(r, PURE, "No Grasp"), *_class_count(r, G3D, "No Grasp"),
                              "No Grasp share")]


APPROX_128, EXACT_128, EXACT_224 = "goal2d", "goal2d_exact", "goal2d_exact_224"


def _f4(r):
    return [claims.rate_less(*_sr(r, APPROX_128), *_sr(r, EXACT_128), strict=False),
            claims.rate_less(*_sr(r, EXACT_128), *_sr(r, EXACT_224))]


DINO_CLS, DINO_GRID, DINO_DENSE, SPOT = "dino_cls", "dino_grid4", "dino_dense", "spot"
OFFLINE_SLOTS = "encoder_slots_ssl"


def _f5(r):
    # SPOT where its weights are given, else the offline slot encoder
    slots = SPOT if r.get(SPOT) and r[SPOT].status is None else OFFLINE_SLOTS
    return [claims.rate_less(*_sr(r, DINO_CLS), *_sr(r, slots)),
            claims.rate_less(*_sr(r, DINO_GRID), *_sr(r, slots)),
            claims.rate_at_most(*_sr(r, DINO_DENSE), 0.05)]


SLOT_TRANSFORMER = "head_slot_transformer"


def _f6(r):
    run = TRAINING_TIME  # the study's heads: one 30-episode training-time run each
    return [claims.rate_less(*_sr(r, other, run), *_sr(r, SLOT_TRANSFORMER, run), strict=False)
            for other in r if other != SLOT_TRANSFORMER]


CONCAT, CROSS_ATTENTION = "fusion_concat", "fusion_cross_attention"


def _f7(r):
    return [claims.rate_less(*_sr(r, CONCAT, TRAIN_SEEDS), *_sr(r, CROSS_ATTENTION, TRAIN_SEEDS),
                             "training-seed SR"),
            claims.rate_equal(*_sr(r, CONCAT), *_sr(r, CROSS_ATTENTION), "held-out SR")]


T5, T20, T40 = "pure_visual", "window20", "window40"


def _f8(r):
    return [claims.rate_equal(*_sr(r, T5), *_sr(r, T20)), claims.rate_equal(*_sr(r, T5), *_sr(r, T40)),
            claims.values_greater(*_peak_returns(r, T5), *_peak_returns(r, T20), "reward at peak", "reward"),
            claims.values_greater(*_peak_returns(r, T20), *_peak_returns(r, T40), "reward at peak", "reward")]


DOF7, GLOBAL9, GROUPED9 = "pure_visual", "proprio9_global", "proprio9_grouped"


def _f9(r):
    return [claims.rate_less(*_sr(r, GLOBAL9), *_sr(r, DOF7)), claims.rate_at_most(*_sr(r, GLOBAL9), 0.05),
            claims.rate_less(*_sr(r, GROUPED9), *_sr(r, DOF7))]


UNIFORM = "goal2d"


def _f10(r):
    return [claims.rate_less(*_sr(r, w), *_sr(r, UNIFORM), strict=False) for w in r if w != UNIFORM]


def _f11(r):
    return [claims.rate_less(*_sr(r, STACK_NATIVE), *_sr(r, STACK_ALIGNED))]


def _f12(r):
    return [claims.rate_above(*_failures_of(r, STACK_ALIGNED, "No Grasp"), 0.5, "No Grasp share of failures")]


FINDINGS = (
    Finding(1, "table5_1", "SR: Pure Visual < 2D < 3D", "31.0 / 55.0 / 71.7 %", (PURE, G2D, G3D), (STABILITY,), _f1),
    Finding(2, "table5_1", "episode length: Pure Visual > 2D > 3D", "313 / 247 / 182 steps", (PURE, G2D, G3D),
            (STABILITY,), _f2),
    Finding(3, "table5_2", "Near Miss share falls from Pure Visual to 3D; No Grasp about the same",
            "Near Miss 31.0 / 21.0 / 2.5 %; No Grasp 7.5 / 7.5 / 12.0 %", (PURE, G3D), (FAILURES,), _f3),
    Finding(4, "table5_3", "SR: approx-128 <= exact-128 < exact-224", "55.0 / 58.7 / 68.7 %",
            (APPROX_128, EXACT_128, EXACT_224), (STABILITY,), _f4),
    Finding(5, "table5_4", "slots above DINO CLS and DINO 4x4; dense DINO near zero",
            "SPOT 55.0; CLS 32.6; 4x4 31.7; dense 1.0 % (peak)", (DINO_CLS, DINO_GRID, DINO_DENSE, OFFLINE_SLOTS),
            (STABILITY,), _f5),
    Finding(6, "table5_5", "Slot Transformer at least as good as the other heads (qualitative)",
            "13.3 against 10.0 / 6.7 / 10.0 % (30 episodes)", (), (TRAINING_TIME,), _f6,
            requires=(SLOT_TRANSFORMER,)),
    Finding(7, "table5_6", "cross-attention fits the training seeds better than concatenation, both equal held out "
            "(so its gap is larger)", "training seeds 60.0 vs 38.6 %; held out 31.0 vs 31.0 %",
            (CONCAT, CROSS_ATTENTION), (STABILITY, TRAIN_SEEDS), _f7),
    Finding(8, "table5_7", "one training budget: SR does not change with T; reward at peak falls as T grows",
            "SR 6.7 / 6.7 / 6.7 %; reward at peak 70 / 45 / 36", (T5, T20, T40), (STABILITY, BEST, SWEEP), _f8),
    Finding(9, "table5_8", "9-DoF with global z-score fails (gripper stuck closed); grouped below 7-DoF",
            "0.0 / 6.7 / 31.0 %", (DOF7, GLOBAL9, GROUPED9), (STABILITY,), _f9),
    Finding(10, "table5_9", "every loss weighting at or below uniform",
            "uniform 55.0; time 38.9; U-shaped 34.8; dim-decoupled 49.8 %", (), (STABILITY,), _f10,
            requires=(UNIFORM,)),
    Finding(11, "table5_10", "StackCube: aligned above native", "native 1.5 %; aligned 5.3 %",
            (STACK_NATIVE, STACK_ALIGNED), (STABILITY,), _f11),
    Finding(12, "table5_11", "StackCube failures are mostly No Grasp", "No Grasp 72.0 %, Near Miss 10.0 %",
            (STACK_ALIGNED,), (FAILURES,), _f12),
)
BY_ID = {f.id: f for f in FINDINGS}
# the findings a group target reports, those its tables cover (findings_main: 1-3, findings_ablations: 4-10,
# findings_stackcube: 11-12); `all` reports the twelve
SCOPES = {"findings": tuple(BY_ID),
          **{f"findings_{scope}": tuple(f.id for f in FINDINGS if TABLES[f.table].scope == scope)
             for scope in registry.SCOPES}}


def by_experiment(rows: list[Row]) -> dict[str, Row]:
    """A table's rows keyed by the experiment each runs, as the findings compare them."""
    out = {r.exp: r for r in rows}
    if len(out) < len(rows):
        twice = sorted({r.exp for r in rows if sum(s.exp == r.exp for s in rows) > 1})
        raise ConfigError(f"a table runs experiment {', '.join(map(repr, twice))} in two rows: the findings cannot "
                          "tell them apart (config `tables`)")
    return out


def config_problems(config: dict) -> list[str]:
    """What in config `tables` the study cannot report: a table the registry does not define, a table whose rows
    leave out an experiment one of the findings compares (naming the finding), or a row that departs where the
    table's variable would be reached around (conditions.barred)."""
    out = [f"tables.{name}: not a table of the study (ocpipe.study.registry defines {', '.join(TABLES)})"
           for name in config["tables"] if name not in TABLES]
    if SPATIAL_FIGURES_TABLE not in config["tables"]:
        out.append(f"tables.{SPATIAL_FIGURES_TABLE}: missing; every profile needs it, since the main target's "
                   "figures and its diagnostics read its rows")
    for f in FINDINGS:
        if f.table not in config["tables"]:
            continue  # a target that reports the finding names the missing table (targets.rows)
        runs = list(config["tables"][f.table].values())
        out += [f"tables.{f.table}: no row runs experiment {exp!r}, which finding {f.id} ({f.claim}) compares"
                for exp in f.compared if exp not in runs]
        out += [f"tables.{f.table}: experiment {exp!r} runs in two rows; finding {f.id} could not tell them apart"
                for exp in sorted(set(runs)) if runs.count(exp) > 1 and exp in f.compared]
    return out + [p for name in config["tables"] if name in TABLES for p in conditions.barred(config, name)]


def check_config(config: dict) -> None:
    """Refuse a config whose tables the study cannot report (config_problems), naming each problem."""
    problems = config_problems(config)
    if problems:
        raise ConfigError("; ".join(problems))


def not_run(finding: Finding, rows: dict[str, Row]) -> str | None:
    """Why a finding cannot be judged (an experiment missing from the table, or a row that needs weights), or None;
    ``rows`` by experiment."""
    missing = [exp for exp in finding.compared if exp not in rows]
    if missing:
        return f"not run: {finding.table} has no row of experiment {', '.join(map(repr, missing))}"
    blocked = {row.label: row.status for exp, row in rows.items()
               if row.status and (exp in finding.rows or not finding.rows)}
    if blocked:
        return "not run: " + "; ".join(f"{label} {why}" for label, why in blocked.items())
    return None


def judge(finding: Finding, rows: dict[str, Row]) -> dict:
    """One line of the findings table; ``rows`` by experiment."""
    base = {"Finding": finding.id, "Table": registry.table_number(finding.table),
            "Claim": finding.claim, "Study": finding.study}
    reason = not_run(finding, rows)
    if reason:
        return {**base, "This build": None, "Test": None, "p": None, "Resolvable at 80 % power": None,
                "Verdict": reason}
    checks = finding.judge(rows)
    resolvable = [c.resolvable for c in checks if c.resolvable]
    return {**base, "This build": "; ".join(c.text for c in checks),
            "Test": "; ".join(f"{c.test} p={c.p:.3g}" if c.p is not None else c.test for c in checks),
            "p": finding_p(checks), "Resolvable at 80 % power": "; ".join(resolvable) or None,
            "Verdict": verdict_of(checks, rows)}


def finding_p(checks: list[pooled.Check]) -> float | None:
    """A finding's p: the largest of its directional checks' (every one of its claims must hold)."""
    p = [c.p for c in checks if c.directional and c.p is not None]
    return max(p) if p else None


def verdict_of(checks: list[pooled.Check], rows: dict[str, Row]) -> str:
    """The verdict of a finding's checks; 'about the same' and 'at most' claims have an equivalence margin only
    where each row is several policies (tested with the policy as the unit)."""
    replicated = min((r.policies for r in rows.values() if r.status is None), default=1) > 1
    return by_policy.verdict([c.outcome for c in checks], by_policy.MARGIN if replicated else None)
