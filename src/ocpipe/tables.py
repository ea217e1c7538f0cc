"""The study's tables, assembled from evaluation Parquet files (SPEC section 10)."""

from __future__ import annotations

import numpy as np
import polars as pl

from . import taxonomy
from .atomic import atomic_path
from .evaluation import success_rate

TABLE5_2_CLASSES = ("Success", "Near Miss", "Drop", "No Grasp", "Idle", "Unknown")


def _std(values: list[float]) -> float:
    # sample standard deviation across independent runs; undefined for a single run
    return float(np.std(values, ddof=1)) if len(values) > 1 else float("nan")


def stability_summary(episodes: pl.DataFrame) -> dict:
    """SR and mean episode length per stability run, as mean and std over runs (trivial successes excluded)."""
    srs, lengths, sizes = [], [], []
    for _, run in episodes.group_by("run", maintain_order=True):
        kept = run.filter(~pl.col("trivial"))
        srs.append(success_rate(run))
        lengths.append(float(kept["steps"].mean()) if len(kept) else float("nan"))
        sizes.append(len(run))
    return {"sr_mean": float(np.mean(srs)), "sr_std": _std(srs), "length_mean": float(np.mean(lengths)),
            "length_std": _std(lengths), "episodes_per_run": int(np.median(sizes)), "runs": len(srs),
            "trivial_excluded": int(episodes["trivial"].sum())}


def table5_1(methods: dict[str, pl.DataFrame]) -> pl.DataFrame:
    """methods: Method -> its stability episodes (all runs)."""
    rows = []
    for method, eps in methods.items():
        s = stability_summary(eps)
        rows.append({"Method": method, "SR mean": s["sr_mean"], "SR std": s["sr_std"],
                     "Episode length mean": s["length_mean"], "Episode length std": s["length_std"],
                     "Episodes per run": s["episodes_per_run"], "Runs": s["runs"],
                     "Trivial excluded": s["trivial_excluded"]})
    return pl.DataFrame(rows)


def table5_2(methods: dict[str, pl.DataFrame]) -> pl.DataFrame:
    """methods: Method -> its per-episode failure classes. Counts and % of non-trivial episodes."""
    rows = []
    for method, classes in methods.items():
        c = taxonomy.counts(classes)
        total = sum(c.values())
        extra = {k: v for k, v in c.items() if k not in TABLE5_2_CLASSES and v}
        row = {"Method": method}
        for name in TABLE5_2_CLASSES + tuple(extra):
            row[name] = c[name]
            row[f"{name} %"] = 100.0 * c[name] / total if total else float("nan")
        row["Total"] = total
        rows.append(row)
    return pl.DataFrame(rows, infer_schema_length=None)


def write_csv(table: pl.DataFrame, path) -> None:
    with atomic_path(path) as tmp:
        table.write_csv(tmp, float_precision=4)
