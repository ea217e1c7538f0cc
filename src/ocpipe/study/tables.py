"""The study's tables, assembled from evaluation Parquet files (docs/study.md, Tables and figures)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import polars as pl

from ..evaluation import taxonomy
from ..stats import by_policy, pooled
from ..util.atomic import atomic_path
from .inputs import BEST, CHECKPOINTS, STABILITY, TRAIN_LOG, TRAIN_SEEDS, TRAINING_TIME, Input

TABLE5_2_CLASSES = ("Success", "Near Miss", "Drop", "No Grasp", "Idle", "Unknown")


def _std(values: list[float]) -> float:
    # sample standard deviation across independent runs or policies; undefined for a single one
    return float(np.std(values, ddof=1)) if len(values) > 1 else float("nan")


def _runs_summary(episodes: pl.DataFrame) -> dict:
    """One policy's SR and mean episode length per run, as mean and std over its runs."""
    if "checkpoint" in episodes.columns and episodes["checkpoint"].n_unique() > 1:
        exp = episodes["exp"][0] if "exp" in episodes.columns else "a policy"
        raise ValueError(f"{exp}: its episodes hold checkpoints "
                         f"{sorted(episodes['checkpoint'].unique().to_list())}, where a table reads the policy's "
                         "best one alone (results from before the fix of the stability rule: rerun them with "
                         "snakemake --forcerun stability)")
    srs, lengths, sizes = [], [], []
    for _, run in episodes.group_by("run", maintain_order=True):
        kept = run.filter(~pl.col("trivial"))
        srs.append(pooled.success_rate(run))
        lengths.append(float(kept["steps"].mean()) if len(kept) else float("nan"))
        sizes.append(len(run))
    k, n = pooled.successes(episodes)
    return {"sr_mean": float(np.mean(srs)), "sr_std": _std(srs), "length_mean": float(np.mean(lengths)),
            "length_std": _std(lengths), "episodes_per_run": int(np.median(sizes)), "runs": len(srs),
            "trivial_excluded": int(episodes["trivial"].sum()), "successes": k, "judged": n}


def per_policy(episodes: pl.DataFrame) -> list[pl.DataFrame]:
    """A row's frame (episodes, classes, logs) split into its policies', in replicate order."""
    if "policy" not in episodes.columns:
        return [episodes]
    return [p for _, p in episodes.sort("policy", maintain_order=True).group_by("policy", maintain_order=True)]


def stability_summary(episodes: pl.DataFrame) -> dict:
    """SR and mean episode length (trivial successes excluded). One policy: mean and std over its runs. K policies
    (a ``policy`` column): each policy's SR and mean length, as mean, std and 95 % t interval over the policies, and
    beside them the episode noise of one policy's SR (binomial, sqrt(mean p (1 - p) / n)): the spread a policy's
    episodes alone would show."""
    per = [_runs_summary(p) for p in per_policy(episodes)]
    if len(per) == 1:
        return {**per[0], "policies": 1}
    srs = [p["sr_mean"] for p in per]
    counts = [(p["successes"], p["judged"]) for p in per]
    # the interval's SD floored at one policy's binomial noise (by_policy.Welch's floor): policies that happen to
    # agree exactly (all at 0 of 40) do not make a row's mean certain
    sd = _std(srs)
    if all(n for _, n in counts):
        k, n = (sum(c) for c in zip(*counts, strict=True))
        sd = float(np.sqrt(by_policy.PolicyValues.of_counts(counts).variance((k + 0.5) / (n + 1))))
    half = pooled.t_half_width(srs, sd=sd)
    noise = np.mean([p["sr_mean"] * (1 - p["sr_mean"]) / p["judged"] for p in per if p["judged"]])
    mean = float(np.mean(srs))  # the interval clipped to the rates a success rate can take
    return {"sr_mean": mean, "sr_std": _std(srs), "sr_low": max(0.0, mean - half), "sr_high": min(1.0, mean + half),
            "sr_episode_std": float(np.sqrt(noise)),
            "length_mean": float(np.nanmean([p["length_mean"] for p in per])),
            "length_std": _std([p["length_mean"] for p in per]), "episodes_per_run": per[0]["episodes_per_run"],
            "runs": per[0]["runs"], "trivial_excluded": int(episodes["trivial"].sum()), "policies": len(per),
            "policy_srs": srs, "policy_counts": counts}


def table5_2(methods: dict[str, pl.DataFrame], always: tuple[str, ...] = ()) -> pl.DataFrame:
    """methods: Method -> its per-episode failure classes. Counts and % of non-trivial episodes; classes beyond
    Table 5.2's appear when some method has them, or always when named in ``always`` (Table 5.11)."""
    rows = []
    for method, classes in methods.items():
        c = taxonomy.counts(classes)
        total = sum(c.values())
        extra = {k: v for k, v in c.items() if k not in TABLE5_2_CLASSES and (v or k in always)}
        row = {"Method": method}
        for name in TABLE5_2_CLASSES + tuple(extra):
            row[name] = c[name]
            row[f"{name} %"] = 100.0 * c[name] / total if total else float("nan")
        row["Total"] = total
        rows.append(row)
    return pl.DataFrame(rows, infer_schema_length=None)


def write_csv(table: pl.DataFrame, path) -> None:
    """Floats to 4 decimals, but p-values (a column named 'p' or 'p ...') at full precision: 0.0000 would hide a
    p of 2.1e-06, and a reader comparing p against a threshold needs the number itself."""
    p_values = [c for c in table.columns if (c == "p" or c.startswith("p ")) and table[c].dtype.is_float()]
    with atomic_path(path) as tmp:
        table.with_columns(pl.col(p_values).cast(pl.String)).write_csv(tmp, float_precision=4)


@dataclass
class Row:
    """One table row: an experiment's settings and the artefacts its table reads (empty when it cannot run)."""

    label: str
    policy: dict
    data: dict = field(default_factory=dict)
    exp: str = ""  # the experiment the row runs (config `tables`: label -> experiment)
    status: str | None = None  # why the row has no results (weights not given)
    visual_tokens: int | None = None  # per timestep, all cameras
    policies: int = 1  # trained policies behind the row (config `replicates`)


SPREAD_COLUMNS = ("SR mean", "SR std over policies", "SR 95 % low", "SR 95 % high", "SR episode std (one policy)",
                  "Episode length mean", "Episode length std over policies")


def _stability(row: Row) -> dict:
    """One policy per row: SR and length, mean and std over its stability runs. K policies: mean, std and 95 %
    interval over the policies, with one policy's episode noise beside them (stability_summary)."""
    if row.status:  # the columns its table's other rows have
        return dict.fromkeys(SPREAD_COLUMNS if row.policies > 1 else ("SR mean", "SR std", "Episode length mean",
                                                                      "Episode length std"))
    s = stability_summary(row.data[STABILITY])
    if s["policies"] == 1:
        return {"SR mean": s["sr_mean"], "SR std": s["sr_std"], "Episode length mean": s["length_mean"],
                "Episode length std": s["length_std"]}
    return dict(zip(SPREAD_COLUMNS, (s["sr_mean"], s["sr_std"], s["sr_low"], s["sr_high"], s["sr_episode_std"],
                                     s["length_mean"], s["length_std"]), strict=True))


def _minutes_per_epoch(row: Row):
    return None if row.status else float(row.data[TRAIN_LOG]["seconds"].mean()) / 60.0


def stability_columns(row: Row) -> dict:
    """SR and episode length, mean and std over the stability runs (Tables 5.1, 5.10)."""
    return _stability(row)


def calibration_columns(row: Row) -> dict:
    return {"Calibration": row.policy["goal_calibration"], "Resolution": row.policy["resolution"], **_stability(row)}


def representation_columns(row: Row) -> dict:
    p = row.policy
    return {"Encoder": p["encoder"], "Visual tokens": row.visual_tokens, "T": p["window"], "H": p["horizon"],
            "Batch": p["batch_size"], "Minutes/epoch": _minutes_per_epoch(row), **_stability(row)}


def _parameters(row: Row) -> int:
    facts = row.data[CHECKPOINTS]
    if facts["parameters"] is None:
        raise ValueError(f"{facts['checkpoint']}: a checkpoint from before training recorded its parameter count; "
                         f"delete its run folder under results/runs/ and rerun the workflow to retrain it")
    return int(facts["parameters"])


def _one_run(row: Row, need: Input) -> dict:
    """SR of one run per policy (trivial successes excluded) with its 95 % interval (one policy: Wilson's over its
    episodes; K policies: t over the policies' SRs), and the mean episode length."""
    if row.status:
        return {"SR": None, "SR 95 % low": None, "SR 95 % high": None, "Episode length mean": None}
    s = stability_summary(row.data[need])
    low, high = (s["sr_low"], s["sr_high"]) if s["policies"] > 1 else pooled.interval(*pooled.successes(row.data[need]))
    return {"SR": s["sr_mean"], "SR 95 % low": low, "SR 95 % high": high, "Episode length mean": s["length_mean"]}


def head_columns(row: Row) -> dict:
    """Table 5.5: one training-time run per head (the study's were 30 episodes each, read qualitatively)."""
    return {"Head": row.policy["visual_head"],
            "Parameters": None if row.status else _parameters(row),
            **_one_run(row, TRAINING_TIME)}


def generalization_columns(row: Row) -> dict:
    s = _stability(row)
    # like the held-out SR: the mean of the policies' own rates
    train_sr = None if row.status else stability_summary(row.data[TRAIN_SEEDS])["sr_mean"]
    gap = None if train_sr is None or s["SR mean"] is None else train_sr - s["SR mean"]
    return {"Fusion": row.policy["fusion"], "Training-seed SR": train_sr, "Held-out SR": s["SR mean"],
            "Held-out SR std": s.get("SR std", s.get("SR std over policies")), "Gap": gap}


def window_columns(row: Row) -> dict:
    """Table 5.7; with K policies, each policy's best epoch and the mean over policies of the reward at its peak."""
    p = row.policy
    best = [] if row.status else row.data[BEST]
    peaks = [r["mean_return"] for b in best for r in b.get("sweep", []) if r["checkpoint"] == b["epoch"]]
    epochs = [b["epoch"] for b in best]
    seq = None if row.status else row.data[CHECKPOINTS]["sequence_length"]
    return {"T": p["window"], "Sequence length": seq, "Minutes/epoch": _minutes_per_epoch(row), "Epochs": p["epochs"],
            "Best epoch": (epochs[0] if len(epochs) == 1 else ", ".join(map(str, epochs))) if epochs else None,
            "Reward at peak": float(np.mean(peaks)) if peaks else None, **_stability(row)}


def setting_columns(header: str, key: str):
    """Columns of a table whose rows differ in one policy setting: that setting, then SR and episode length."""
    return lambda row: {header: row.policy[key], **_stability(row)}


def build(columns, rows: list[Row]) -> pl.DataFrame:
    """A table of stability (or training-time) results: one row per Row, ``columns(row)`` (a registry entry's
    columns) after its label, then how many episodes and runs it rests on. Failure distributions come from
    table5_2 instead."""
    out = []
    for row in rows:
        r = {"Method": row.label, **columns(row)}
        runs = next((row.data[k] for k in (STABILITY, TRAINING_TIME) if k in row.data), None)
        if row.status is None and runs is not None:
            s = stability_summary(runs)
            r |= {"Episodes per run": s["episodes_per_run"], "Runs": s["runs"],
                  "Trivial excluded": s["trivial_excluded"]}
            if s["policies"] > 1:
                r["Policies"] = s["policies"]
        out.append(r)
    frame = pl.DataFrame(out, infer_schema_length=None)
    if any(r.status for r in rows):
        frame = frame.with_columns(pl.Series("Status", [r.status or "ok" for r in rows]))
    return frame
