"""The study's tables and figures, one entry each: adding a table is one entry here (its title, what it reads per
row, its columns) plus its rows in config `tables` (row label -> experiment).

A table reads, for every row, a fixed set of per-experiment artefacts ("needs": stability runs, failure classes,
the training log, ...; `targets.artefacts` says which files). A table with ``columns`` is a table of stability
results (`tables.build`); one without is a failure distribution (`tables.table5_2`). A figure draws the rows of
a table, reading its own needs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from . import figures, tables


@dataclass(frozen=True)
class Table:
    title: str
    needs: tuple[str, ...]
    columns: Callable[[tables.Row], dict] | None = None  # None: a failure distribution
    always_classes: tuple[str, ...] = ()  # failure distributions: classes shown even when no episode has them


@dataclass(frozen=True)
class Figure:
    table: str  # whose rows it draws
    needs: tuple[str, ...]
    draw: Callable[[list[tables.Row], object], None]  # (the table's rows, output png)


TABLES = {
    "table5_1": Table("Table 5.1: spatial grounding (held-out SR, mean episode length)", ("stability",),
                      tables.stability_columns),
    "table5_2": Table("Table 5.2: failure distribution", ("failures",)),
    "table5_3": Table("Table 5.3: goal calibration x resolution", ("stability",), tables.calibration_columns),
    "table5_4": Table("Table 5.4: visual representations", ("stability", "train_log"), tables.representation_columns),
    "table5_5": Table("Table 5.5: single-camera slot heads (base camera, no goal)", ("stability", "checkpoints"),
                      tables.head_columns),
    "table5_6": Table("Table 5.6: multi-view fusion, generalization gap (training-seed SR vs held-out SR)",
                      ("stability", "train_seeds"), tables.generalization_columns),
    "table5_7": Table("Table 5.7: temporal window T", ("stability", "train_log", "best", "checkpoints"),
                      tables.window_columns),
    "table5_8": Table("Table 5.8: proprioception and normalization", ("stability",),
                      tables.setting_columns("Proprio", "proprio")),
    "table5_9": Table("Table 5.9: loss weighting by episode progress", ("stability",),
                      tables.setting_columns("Loss weighting", "loss_weighting")),
    "table5_10": Table("Table 5.10: StackCube, native (base + hand camera, no goal) vs aligned (base + side, 2D goal)",
                       ("stability",), tables.stability_columns),
    "table5_11": Table("Table 5.11: StackCube failure distribution", ("failures",), always_classes=("Grasp No Stack",)),
}


def _classes(rows):
    """Row label -> failure classes, for the rows that have results."""
    return {r.label: r.data["failures"] for r in rows if r.status is None}


FIGURES = {
    "fig5_5": Figure("table5_4", ("stability",), lambda rows, png: figures.sr_bars(
        rows, png, "Success rate by visual representation (mean ± std over stability runs)")),
    "fig5_6": Figure("table5_9", ("failures",), lambda rows, png: figures.fig5_3(
        _classes(rows), png, title="Failure distribution by loss weighting")),
    "fig5_7": Figure("table5_10", ("failures",), lambda rows, png: figures.funnel(_classes(rows), png)),
}

# figures 5.1-5.3 draw Table 5.1's rows together (one rule): training curves, sweeps, stability runs, failures
SPATIAL_FIGURES_NEEDS = ("train_log", "sweep", "stability", "failures")
