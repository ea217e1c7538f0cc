"""The study's tables and figures, one entry each: adding a table is one entry here (its title, what it reads per
row, its columns) plus its rows in config `tables` (row label -> experiment).

A table reads, for every row, a fixed set of per-policy inputs (`inputs`: stability runs, failure classes, the
training log, ...; each knows its files and how to read them). A table with ``columns`` is a table of stability
results (`tables.build`); one without is a failure distribution (`tables.table5_2`). A figure draws the rows of
a table, reading its own needs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from . import figures, tables
from .inputs import BEST, CHECKPOINTS, FAILURES, STABILITY, SWEEP, TRAIN_LOG, TRAIN_SEEDS, TRAINING_TIME, Input


@dataclass(frozen=True)
class Table:
    title: str
    needs: tuple[Input, ...]
    scope: str  # the group target that builds it and judges its findings (SCOPES)
    columns: Callable[[tables.Row], dict] | None = None  # None: a failure distribution
    always_classes: tuple[str, ...] = ()  # failure distributions: classes shown even when no episode has them
    varies: tuple[str, ...] = ()  # the policy settings the study varied between this table's rows; nothing else may
    fixed: str = ""  # what the study held fixed across the rows, in words (written under the table)
    # experiment -> further settings that one row may differ in, each with the study's reason
    allowed: dict[str, tuple[str, ...]] = field(default_factory=dict)
    # settings every row must hold at these values, beside EVERY_TABLE_HOLDS: a departure that would reach the rows
    # around the variable under study (docs/study.md, how each table's variable reaches its rows)
    holds: dict[str, object] = field(default_factory=dict)


# no table's row may hand the policy the goal minus the hand: it changes the goal input Table 5.1 studies and
# cancels the calibration error Table 5.3 measures (a lever only, on the validation pool)
EVERY_TABLE_HOLDS = {"goal_relative": "none"}
# the object read-out reads the pose off every camera's tokens: a path around the encoder (5.4), the slot head
# (5.5) and the fusion (5.6); visual dropout served the read-out, so it goes with it
WITHOUT_READOUT = {"object_readout": False, "readout_scenes": False, "visual_dropout": 0.0}


# the privileged-state control reads the object's true pose instead of rendered tokens: no camera, no read-out,
# and no visual token to blank (its one token is the pose)
CONTROL = {"state_control": ("goal", "encoder", "cameras", "object_readout", "readout_scenes", "visual_dropout")}
# dense DINO fits in memory only this way (the study's own exception, a column of its Table 5.4)
DENSE = {"dino_dense": ("window", "horizon", "batch_size")}
SPATIAL = "encoder, cameras (base + side) and resolution 128 px, T, H, demos and training"


# the group targets (Snakefile): the main job (spatial_grounding), the ablations on PickCube, and StackCube
SCOPES = ("main", "ablations", "stackcube")


@dataclass(frozen=True)
class Figure:
    table: str  # whose rows it draws
    needs: tuple[Input, ...]
    draw: Callable[[list[tables.Row], object], None]  # (the table's rows, output png)


TABLES = {
    "table5_1": Table("Table 5.1: spatial grounding (held-out SR, mean episode length)", (STABILITY,), "main",
                      tables.stability_columns, varies=("goal",), fixed=SPATIAL, allowed=CONTROL),
    "table5_2": Table("Table 5.2: failure distribution", (FAILURES,), "main", varies=("goal",), fixed=SPATIAL,
                      allowed=CONTROL),
    "table5_3": Table("Table 5.3: goal calibration x resolution", (STABILITY,), "ablations",
                      tables.calibration_columns, varies=("goal_calibration", "resolution"),
                      fixed="encoder, both cameras, 2D goal, T, H"),
    "table5_4": Table("Table 5.4: visual representations", (STABILITY, TRAIN_LOG), "ablations",
                      tables.representation_columns, varies=("encoder",),
                      fixed="both cameras at 128 px, approximate calibration, 2D goal, the policy", allowed=DENSE,
                      holds=WITHOUT_READOUT),
    "table5_5": Table("Table 5.5: single-camera slot heads (base camera, no goal; one training-time run each)",
                      (TRAINING_TIME, CHECKPOINTS), "ablations", tables.head_columns, varies=("visual_head",),
                      fixed="slot encoder, base camera only (7 slots), no goal, 7-DoF proprioception",
                      holds=WITHOUT_READOUT),
    "table5_6": Table("Table 5.6: multi-view fusion, generalization gap (training-seed SR vs held-out SR)",
                      (STABILITY, TRAIN_SEEDS), "ablations", tables.generalization_columns, varies=("fusion",),
                      fixed="slot encoder, both cameras, no goal", holds=WITHOUT_READOUT),
    "table5_7": Table("Table 5.7: temporal window T", (STABILITY, TRAIN_LOG, BEST, CHECKPOINTS), "ablations",
                      tables.window_columns, varies=("window", "epochs"),
                      fixed="slot encoder, both cameras, no goal, one training budget per row (epochs in the "
                            "study's 680 : 300 : 150 proportion)"),
    "table5_8": Table("Table 5.8: proprioception and normalization", (STABILITY,), "ablations",
                      tables.setting_columns("Proprio", "proprio"), varies=("proprio",),
                      fixed="slot encoder, both cameras, no goal"),
    "table5_9": Table("Table 5.9: loss weighting by episode progress", (STABILITY,), "ablations",
                      tables.setting_columns("Loss weighting", "loss_weighting"), varies=("loss_weighting",),
                      fixed="slot encoder, both cameras at 128 px, approximate calibration, 2D goal"),
    "table5_10": Table("Table 5.10: StackCube, native (base + hand camera, no goal) vs aligned (base + side, 2D goal)",
                       (STABILITY,), "stackcube", tables.stability_columns, varies=("cams", "goal"),
                       fixed="StackCube, slot encoder, T, H, demos"),
    "table5_11": Table("Table 5.11: StackCube failure distribution (aligned)", (FAILURES,), "stackcube",
                       always_classes=("Grasp No Stack",), fixed="StackCube aligned (base + side, 2D goal)"),
}


def _classes(rows):
    """Row label -> failure classes, for the rows that have results."""
    return {r.label: r.data[FAILURES] for r in rows if r.status is None}


FIGURES = {
    "fig5_5": Figure("table5_4", (STABILITY,), lambda rows, png: figures.sr_bars(
        rows, png, "Success rate by visual representation (mean ± std over stability runs)")),
    "fig5_6": Figure("table5_9", (FAILURES,), lambda rows, png: figures.fig5_3(
        _classes(rows), png, title="Failure distribution by loss weighting")),
    "fig5_7": Figure("table5_10", (FAILURES,), lambda rows, png: figures.funnel(_classes(rows), png)),
}


_unknown = {name: t.scope for name, t in TABLES.items() if t.scope not in SCOPES}
if _unknown:  # a misspelt scope would leave the table out of every group target
    raise ValueError(f"tables with a scope not in {SCOPES}: {_unknown}")


def table_number(table: str) -> str:
    """'5.10' of table5_10: the number its title gives."""
    return TABLES[table].title.split(":")[0].removeprefix("Table ")


def tables_in(scope: str) -> list[str]:
    """The tables a group target builds, in registry order."""
    if scope not in SCOPES:
        raise ValueError(f"unknown scope {scope!r} (scopes: {', '.join(SCOPES)})")
    return [name for name, spec in TABLES.items() if spec.scope == scope]


def figures_in(scope: str) -> list[str]:
    """The figures drawing the rows of a group target's tables."""
    return [name for name, fig in FIGURES.items() if TABLES[fig.table].scope == scope]


# figures 5.1-5.3 draw Table 5.1's rows together (one rule): training curves, sweeps, stability runs, failures
SPATIAL_FIGURES = ("fig5_1", "fig5_2", "fig5_3")
SPATIAL_FIGURES_JOB = "fig5_1_to_5_3"  # the name its log and benchmark files go by
SPATIAL_FIGURES_TABLE = "table5_1"
SPATIAL_FIGURES_NEEDS = (TRAIN_LOG, SWEEP, STABILITY, FAILURES)
