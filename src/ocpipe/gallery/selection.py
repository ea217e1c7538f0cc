"""Which episodes the gallery shows: for each row of the tables it covers (the main job's and StackCube's) and each
failure class among that row's classified episodes, a few episodes drawn with the config's seed.

A row is an experiment trained as K policies; its episodes are those its policies' failure classification read
(`failures.parquet` of each policy: the stability runs, or a dedicated failure run). Trivial successes, which the
tables leave out, are not shown."""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import polars as pl

from .. import paths
from ..evaluation.taxonomy import CLASSES
from ..study import registry, targets

SCOPES = ("main", "stackcube")  # the group targets whose tables' rows the gallery shows
PARTS = ("videos", "sheets", "episodes.csv")  # what one row's gallery job writes under paths.GALLERY
GALLERY_STREAM = 11  # random stream (root seed, purpose, ...): see evaluation.jobs for the others


def rows(config: dict, scopes: tuple[str, ...] = SCOPES) -> dict[str, dict[str, str]]:
    """Experiment -> {table: row label} over the tables of ``scopes`` (of SCOPES), in table order; rows that cannot
    run with this config (an encoder without its weights) are left out, as the tables leave them."""
    unknown = set(scopes) - set(SCOPES)
    if unknown:
        raise ValueError(f"the gallery covers no scope {sorted(unknown)} (scopes: {', '.join(SCOPES)})")
    out: dict[str, dict[str, str]] = {}
    for scope in scopes:
        for table in registry.tables_in(scope):
            skip = targets.unavailable(config, table)
            for label, exp in targets.rows(config, table).items():
                if label not in skip:
                    out.setdefault(exp, {})[table] = label
    return out


def outputs(exps) -> list[str]:
    """What the gallery jobs of these experiments write (paths relative to the working directory)."""
    return [f"{paths.GALLERY.format(exp=exp)}/{part}" for exp in exps for part in PARTS]


def built(exps, workdir: Path | str = ".") -> list[str]:
    """``outputs`` of the experiments whose gallery is already there, every part of it. A group target takes these
    as inputs, so its report shows a gallery once `snakemake gallery` has drawn it and keeps it in step with the
    tables after that, while a first build of the group never draws one."""
    drawn = []
    for exp in exps:
        parts = outputs([exp])
        if all((Path(workdir) / f).exists() for f in parts):
            drawn += parts
    return drawn


def row_title(tables: dict[str, str]) -> str:
    """How a row is named in the report: ``Tables 5.1, 5.2: 2D-Spatial-Proj`` (its labels joined where tables
    name it differently)."""
    numbers = ", ".join(registry.table_number(t) for t in tables)
    labels = " / ".join(dict.fromkeys(tables.values()))
    return f"Table{'s' if len(tables) > 1 else ''} {numbers}: {labels}"


def slug(failure_class: str) -> str:
    """A class as file names carry it: ``Near Miss`` -> ``near_miss``."""
    if failure_class not in CLASSES:
        raise ValueError(f"unknown failure class {failure_class!r} (classes: {', '.join(CLASSES)})")
    return failure_class.lower().replace(" ", "_")


def class_of_slug(name: str) -> str:
    found = {slug(c): c for c in CLASSES}
    if name not in found:
        raise ValueError(f"{name!r} names no failure class (one of {', '.join(found)})")
    return found[name]


def candidates(classes_by_policy: dict[str, pl.DataFrame]) -> pl.DataFrame:
    """The row's classified episodes (each policy's failures.parquet, in policy order) as one frame with a
    ``policy`` column, trivial successes left out."""
    frames = []
    for order, (pid, classes) in enumerate(classes_by_policy.items()):
        missing = {"run", "seed", "trivial", "class"} - set(classes.columns)
        if missing:
            raise ValueError(f"failure classes of policy {pid}: no column {', '.join(sorted(missing))}")
        frames.append(classes.select("run", "seed", "trivial", "class")
                      .with_columns(policy=pl.lit(pid), policy_order=pl.lit(order)))
    if not frames:
        raise ValueError("no policies: a row needs at least one policy's failure classes")
    return pl.concat(frames, how="vertical").filter(~pl.col("trivial")).drop("trivial")


def pick(episodes: pl.DataFrame, per_class: int, seed: int, row: str = "") -> pl.DataFrame:
    """``per_class`` episodes of each failure class present (all of a class with fewer), drawn without replacement
    from a generator seeded by (``seed``, the gallery's stream, the row, the class), so the picks are the same on
    every run and a class's picks do not depend on which other classes are present. Rows come out in the taxonomy's
    class order, then in the order the policies and their runs list them; ``n`` numbers a class's picks from 0."""
    if per_class < 1:
        raise ValueError(f"gallery.episodes_per_class must be at least 1, got {per_class}")
    unknown = set(episodes["class"].unique().to_list()) - set(CLASSES)
    if unknown:
        raise ValueError(f"failure classes {sorted(unknown)} are not the taxonomy's ({', '.join(CLASSES)})")
    row_key = zlib.crc32(row.encode())  # a fixed number per row (Python's hash() of a str changes per process)
    picked = []
    for index, failure_class in enumerate(CLASSES):
        pool = episodes.filter(pl.col("class") == failure_class).sort("policy_order", "run", "seed")
        if pool.is_empty():
            continue
        rng = np.random.default_rng([seed, GALLERY_STREAM, row_key, index])
        chosen = np.sort(rng.choice(len(pool), size=min(per_class, len(pool)), replace=False))
        picked.append(pool[chosen.tolist()].with_columns(n=pl.int_range(pl.len())))
    if not picked:
        return episodes.clear().with_columns(n=pl.lit(0, dtype=pl.Int64))
    return pl.concat(picked, how="vertical")


def video_label(class_slug: str, replicate: str, seed: str) -> dict[str, str]:
    """The report's label of a video, from its file name's parts (build: ``{class}-{k}-{seed}.mp4``)."""
    return {"item": f"{class_of_slug(class_slug)}: policy {replicate}, seed {seed}"}


def sheet_label(class_slug: str) -> dict[str, str]:
    """The report's label of a class's contact sheet (build: ``{class}.png``)."""
    return {"item": f"{class_of_slug(class_slug)}: contact sheet"}
