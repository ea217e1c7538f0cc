"""The levers table: every candidate change to the recipe (config `levers.sets`), trained as `levers.replicates`
policies, each evaluated on the same validation-pool episodes, beside its experiment's baseline (the lever of that
experiment without overrides). Each row: what it changes, training time, the open-loop error on held-out demos,
successes, the object read-out's closed-loop error, a two-sided test against the baseline (Fisher's exact test
on one policy each, Welch's t over the policies' SRs with several), and whether the lever may be adopted: a cheaper
or simpler recipe replaces the baseline only where its row loses no resolved amount (the one-sided test of a loss)
and its mean drops by at most `levers.adoption_max_drop_points`."""

from __future__ import annotations

import numpy as np
import polars as pl

from ..stats import by_policy, pooled
from ..util.atomic import atomic_path
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


def lever_row(name: str, lever: dict, policies: list[tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]]) -> dict:
    """One lever from its policies' (train log, episodes, steps): training minutes and open-loop error averaged over
    them, successes per policy and in all."""
    counts = [pooled.successes(eps) for _, eps, _ in policies]
    errors = [log.row(-1, named=True).get("val_joint_err_rad") for log, _, _ in policies]
    readout = [readout_error_cm(steps) for _, _, steps in policies]
    overrides = ", ".join(f"{k}={v}" for k, v in lever.get("policy", {}).items()) or "baseline"
    return {"Lever": name, "Experiment": lever["experiment"], "Changes": overrides, "Policies": len(policies),
            "Train min": round(float(np.mean([log["seconds"].sum() for log, _, _ in policies])) / 60, 1),
            "Open-loop joint error (rad)": None if None in errors else float(np.mean(errors)),
            "Successes": sum(k for k, _ in counts), "Episodes": sum(n for _, n in counts),
            "Read-out error (cm)": None if None in readout else round(float(np.median(readout)), 2),
            "_counts": counts}


def _p_vs_baseline(r: dict, b: dict) -> tuple[float, float] | None:
    """(two-sided p, one-sided p of a loss) against the baseline: Fisher's exact test on one policy each; with
    more, Welch's t over the policies' SRs (by_policy: the policy is the unit). None where a policy judged no
    episode (every success trivial)."""
    if any(n == 0 for _, n in r["_counts"] + b["_counts"]):
        return None
    if r["Policies"] == 1 and b["Policies"] == 1:
        return (pooled.fisher(r["_counts"][0], b["_counts"][0], "two-sided"),
                pooled.fisher(r["_counts"][0], b["_counts"][0], "less"))
    values = (by_policy.PolicyValues.of_counts(x["_counts"]) for x in (r, b))
    w = by_policy.Welch.of(*values)
    return min(1.0, 2 * min(w.p_below(), w.p_above())), w.p_below()


def _adoption(change_points: float, p_loss: float, max_drop_points: float) -> str:
    if p_loss < pooled.ALPHA:
        return f"no: a resolved loss (p = {p_loss:.3f})"
    if change_points < -max_drop_points:
        return f"no: the mean drops by more than {max_drop_points:g} points"
    return "yes"


def with_tests(rows: list[dict], max_drop_points: float) -> pl.DataFrame:
    """Rows with their SR (mean over policies, and its std), the change and the p against their experiment's
    baseline, and whether they may replace it (None where there is no baseline, or no test)."""
    base = {r["Experiment"]: r for r in rows if r["Changes"] == "baseline"}
    for r in rows:
        rates = [k / n for k, n in r["_counts"] if n]
        r["SR"] = float(np.mean(rates)) if rates else None
        r["SR std over policies"] = float(np.std(rates, ddof=1)) if len(rates) > 1 else None
    for r in rows:
        b = base.get(r["Experiment"])
        tests = _p_vs_baseline(r, b) if b is not None and b is not r else None
        r["SR change (points)"] = round(100 * (r["SR"] - b["SR"]), 1) if tests else None
        r["p vs baseline"], r["p of a loss"] = tests or (None, None)
        r["Adoptable"] = _adoption(r["SR change (points)"], r["p of a loss"], max_drop_points) if tests else None
    return pl.DataFrame([{k: v for k, v in r.items() if k != "_counts"} for r in rows])


def write(config: dict, inputs: dict[str, list[tuple]], csv_path, md_path) -> pl.DataFrame:
    """``inputs``: lever name -> its policies' (train log, episodes file, steps file)."""
    sets = config["levers"]["sets"]
    rows = [lever_row(name, sets[name], [tuple(pl.read_parquet(f) for f in files) for files in policies])
            for name, policies in inputs.items()]
    max_drop = config["levers"]["adoption_max_drop_points"]
    table = with_tests(rows, max_drop)
    n, k = config["levers"]["episodes"], max(r["Policies"] for r in rows)
    test = ("Fisher's exact test, two-sided" if k == 1 else
            "Welch's t over the policies' SRs, two-sided (floored at one policy's binomial noise)")
    footer = (f"Profile {config.get('profile', '?')}. Every lever trained as {k} "
              f"{'policy' if k == 1 else 'policies'}, each evaluated on the same {n} seeds of the validation pool "
              f"(never a table's seeds); p: {test}, against the lever of the same experiment without overrides. A "
              f"difference is resolved only where p < {pooled.ALPHA}. p of a loss: the same test, one-sided, of the "
              f"lever below its baseline. Adoptable: no resolved loss and a mean at most {max_drop:g} points below "
              f"the baseline's.")
    with atomic_path(csv_path) as tmp:
        table.write_csv(tmp)
    with atomic_path(md_path) as tmp:
        tmp.write_text(markdown(table, "Levers on the validation pool", footer))
    return table
