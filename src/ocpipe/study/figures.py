"""The study's figures 5.1-5.3 and 5.5-5.7 from training logs and evaluation Parquet files."""

from __future__ import annotations

import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import polars as pl  # noqa: E402

from ..evaluation.taxonomy import FUNNEL, counts  # noqa: E402
from ..evaluation.taxonomy import funnel as funnel_counts
from ..util.atomic import atomic_path  # noqa: E402
from .inputs import STABILITY  # noqa: E402
from .tables import TABLE5_2_CLASSES, per_policy, stability_summary  # noqa: E402


def _save(fig, path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight")
    plt.close(fig)


def _policy_points(ax, x: float, values: list[float]) -> None:
    """Each trained policy's own figure beside its row's bar, so the spread between policies shows."""
    if len(values) > 1:
        offsets = np.linspace(-0.2, 0.2, len(values))
        ax.plot(x + offsets, values, "o", color="black", ms=3.5, alpha=0.7, zorder=3)


def fig5_1(train_logs: dict[str, pl.DataFrame], sweeps: dict[str, pl.DataFrame], path, window: int = 10) -> None:
    """Training loss (raw and rolling mean), mean evaluation return per saved epoch, and (when the training log
    has it) the open-loop joint error on held-out demos per epoch, per method."""
    openloop = any("val_joint_err_rad" in logs.columns for logs in train_logs.values())
    fig, axes = plt.subplots(1, 3 if openloop else 2, figsize=(16 if openloop else 11, 4))
    ax_loss, ax_ret = axes[:2]
    for i, (method, logs) in enumerate(train_logs.items()):
        colour = f"C{i}"
        for policy in per_policy(logs):  # each trained policy's loss, thin
            ax_loss.plot(policy["epoch"], policy["loss"], color=colour, alpha=0.25, lw=1)
        mean = logs.group_by("epoch").agg(pl.col("loss").mean()).sort("epoch")
        rolling = mean["loss"].rolling_mean(window_size=window, min_samples=1)
        ax_loss.plot(mean["epoch"], rolling, color=colour, lw=2, label=method)
        sweep = sweeps[method].group_by("checkpoint").agg(pl.col("return").mean(), pl.col("success").mean())
        sweep = sweep.sort("checkpoint")
        ax_ret.plot(sweep["checkpoint"], sweep["return"], "o-", color=colour, label=method)
        if openloop and "val_joint_err_rad" in logs.columns:
            err = logs.group_by("epoch").agg(pl.col("val_joint_err_rad").mean()).sort("epoch")
            axes[2].plot(err["epoch"], err["val_joint_err_rad"], "o-", color=colour, ms=3, label=method)
    if openloop:
        axes[2].set(xlabel="epoch", ylabel="mean |joint error| (rad)", yscale="log",
                    title="Open-loop action error, held-out demos")
    ax_loss.set(xlabel="epoch", ylabel="training loss", yscale="log",
                title=f"Training loss ({window}-epoch rolling mean)")
    ax_ret.set(xlabel="epoch (checkpoint)", ylabel="mean episode return", title="Evaluation reward per epoch")
    for ax in axes:
        ax.legend()
        ax.grid(alpha=0.3)
    _save(fig, path)


def fig5_2(stability: dict[str, pl.DataFrame], path) -> None:
    """Mean episode length per method: mean ± std over stability runs (one policy) or over policies, each policy's
    own mean as a point."""
    methods = list(stability)
    s = [stability_summary(stability[m]) for m in methods]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.bar(range(len(methods)), [x["length_mean"] for x in s], yerr=[np.nan_to_num(x["length_std"]) for x in s],
           capsize=6, color=[f"C{i}" for i in range(len(methods))])
    for i, m in enumerate(methods):
        _policy_points(ax, i, [stability_summary(p)["length_mean"] for p in per_policy(stability[m])])
    ax.set_xticks(range(len(methods)), methods)
    over = "policies" if any(x["policies"] > 1 for x in s) else "stability runs"
    ax.set(ylabel="mean episode length (steps)", title=f"Episode length over {over} (mean ± std)")
    ax.grid(axis="y", alpha=0.3)
    _save(fig, path)


def fig5_3(classes: dict[str, pl.DataFrame], path, title: str = "Failure distribution") -> None:
    """Failure-class counts per method (grouped bars)."""
    methods = list(classes)
    c = {m: counts(classes[m]) for m in methods}
    names = [n for n in TABLE5_2_CLASSES + ("Grasp No Stack",) if any(c[m].get(n, 0) for m in methods)] or ["Success"]
    x = np.arange(len(names))
    width = 0.8 / max(1, len(methods))
    fig, ax = plt.subplots(figsize=(8, 4))
    for i, m in enumerate(methods):
        ax.bar(x + i * width, [c[m].get(n, 0) for n in names], width, label=m, color=f"C{i}")
    ax.set_xticks(x + width * (len(methods) - 1) / 2, names)
    ax.set(ylabel="episodes", title=title)
    ax.legend()
    ax.grid(axis="y", alpha=0.3)
    _save(fig, path)


def sr_bars(rows, path, title: str) -> None:
    """Held-out SR per table row: mean ± std over stability runs (one policy) or over policies, each policy's SR as
    a point; rows without results say why."""
    fig, ax = plt.subplots(figsize=(1.6 * len(rows) + 2, 4))
    for i, row in enumerate(rows):
        if row.status:  # e.g. "needs weights: set encoders.dino.checkpoint (...)": name the key, not the whole story
            keys = re.findall(r"encoders\.\w+\.\w+", row.status)
            ax.text(i, 0.03, "\n".join([row.status.split(":")[0], *keys[:1]]), rotation=90, ha="center", va="bottom",
                    fontsize=7, color="grey")
            continue
        s = stability_summary(row.data[STABILITY])
        ax.bar(i, s["sr_mean"], yerr=np.nan_to_num(s["sr_std"]), capsize=6, color=f"C{i}")
        _policy_points(ax, i, s.get("policy_srs", []))
    ax.set_xticks(range(len(rows)), [r.label for r in rows], rotation=15, ha="right")
    ax.set(ylabel="success rate", ylim=(0, 1), title=title)
    ax.grid(axis="y", alpha=0.3)
    _save(fig, path)


def funnel(classes: dict[str, pl.DataFrame], path) -> None:
    """StackCube sub-task funnel: episodes reaching grasp -> lift -> near target -> success, per method."""
    stages = list(FUNNEL)
    width = 0.8 / max(1, len(classes))
    fig, ax = plt.subplots(figsize=(8, 4))
    for i, (method, c) in enumerate(classes.items()):
        f = funnel_counts(c)
        ax.bar(np.arange(len(stages)) + i * width, [f[s] for s in stages], width, label=method, color=f"C{i}")
    ax.set_xticks(np.arange(len(stages)) + width * (len(classes) - 1) / 2, stages)
    ax.set(ylabel="episodes reaching the stage", title="StackCube sub-task funnel")
    ax.legend()
    ax.grid(axis="y", alpha=0.3)
    _save(fig, path)
