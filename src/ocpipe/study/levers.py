"""The levers table: every candidate change to the recipe (config `levers.sets`), trained once and evaluated on
the same validation-pool episodes, beside its experiment's baseline (the lever of that experiment without
overrides). Each row: what it changes, training time, the open-loop error on held-out demos, successes, the
object read-out's closed-loop error, and Fisher's exact test (two-sided) against the baseline's successes."""

from __future__ import annotations

import numpy as np
import polars as pl

from ..util.atomic import atomic_path
from . import stats
from .report import markdown


def readout_error_cm(steps: pl.DataFrame) -> float | None:
    """Median distance (cm) between the policy's object read-out and the true object over the closed-loop steps
    before a grasp (after it the object rides in a hand that hides it); None without a read-out."""
    est = np.asarray(steps["obj_est"].to_list(), dtype=np.float64)
    if np.isnan(est).all():
        return None
    free = ~np.asarray(steps["is_grasped"].to_list(), dtype=bool)
    err = 100 * np.linalg.norm(est - np.asarray(steps["obj_pos"].to_list()), axis=1)
    return round(float(np.median(err[free])), 2)


def lever_row(name: str, lever: dict, train_log: pl.DataFrame, episodes: pl.DataFrame, steps: pl.DataFrame) -> dict:
    k, n = stats.successes(episodes)
    overrides = ", ".join(f"{k}={v}" for k, v in lever.get("policy", {}).items()) or "baseline"
    last = train_log.row(-1, named=True)
    return {"Lever": name, "Experiment": lever["experiment"], "Changes": overrides,
            "Train min": round(float(train_log["seconds"].sum()) / 60, 1),
            "Open-loop joint error (rad)": last.get("val_joint_err_rad"),
            "Successes": k, "Episodes": n,
            "Read-out error (cm)": readout_error_cm(steps)}


def with_tests(rows: list[dict]) -> pl.DataFrame:
    """Rows with their SR and Fisher's exact p against their experiment's baseline (None where there is none)."""
    base = {r["Experiment"]: r for r in rows if r["Changes"] == "baseline"}
    for r in rows:
        r["SR"] = r["Successes"] / r["Episodes"] if r["Episodes"] else None
        b = base.get(r["Experiment"])
        r["p vs baseline"] = None
        if b is not None and b is not r:
            r["p vs baseline"] = stats.fisher((r["Successes"], r["Episodes"]), (b["Successes"], b["Episodes"]),
                                              "two-sided")
    return pl.DataFrame(rows)


def write(config: dict, inputs: dict[str, tuple], csv_path, md_path) -> pl.DataFrame:
    """``inputs``: lever name -> (train log, episodes file, steps file)."""
    sets = config["levers"]["sets"]
    rows = [lever_row(name, sets[name], pl.read_parquet(log), pl.read_parquet(eps), pl.read_parquet(steps))
            for name, (log, eps, steps) in inputs.items()]
    table = with_tests(rows)
    n = config["levers"]["episodes"]
    footer = (f"Profile {config.get('profile', '?')}. Every lever trained once and evaluated on the same {n} seeds of "
              "the validation pool (never a table's seeds); p: Fisher's exact test, two-sided, against the lever of "
              "the same experiment without overrides. A difference is resolved only where p < 0.05.")
    with atomic_path(csv_path) as tmp:
        table.write_csv(tmp)
    with atomic_path(md_path) as tmp:
        tmp.write_text(markdown(table, "Levers on the validation pool", footer))
    return table
