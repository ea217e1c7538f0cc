"""Failure taxonomy (docs/study.md, Failure taxonomy) on per-step evaluation logs; the first matching rule wins.

  1 Success         the episode's success flag
  2 Idle            mean over action dims of the per-dim variance over time < idle_variance
  3 No Grasp        never grasped
  4 Drop            grasped at some step but not at the last step
  5 Grasp No Stack  (StackCube) cubeA lifted while grasped but never within stack_near_m of its target on cubeB
  6 Near Miss       min over t of |TCP_t - goal_t| < near_miss_m
  7 Unknown         anything else
StackCube's sub-task funnel counts episodes that reach grasp -> lift -> near target -> success."""

from __future__ import annotations

import numpy as np
import polars as pl

from .. import paths
from ..util.atomic import atomic_path

CLASSES = ("Success", "Idle", "No Grasp", "Drop", "Grasp No Stack", "Near Miss", "Unknown")
FUNNEL = ("episodes", "grasp", "lift", "near target", "success")


def _arr(steps: pl.DataFrame, col: str) -> np.ndarray:
    return np.asarray(steps[col].to_list(), dtype=np.float64)


def tcp_goal_distance(steps: pl.DataFrame) -> np.ndarray:
    """Per step, how far the TCP is from the goal (m): the closest of these decides a Near Miss."""
    return np.linalg.norm(_arr(steps, "tcp_pos") - _arr(steps, "goal_pos"), axis=1)


def obj_goal_distance(steps: pl.DataFrame) -> np.ndarray:
    """Per step, how far the object is from the goal (m): under stack_near_m it is near its target."""
    return np.linalg.norm(_arr(steps, "obj_pos") - _arr(steps, "goal_pos"), axis=1)


def milestones(steps: pl.DataFrame, success: bool, rules: dict) -> dict[str, bool]:
    grasped = np.asarray(steps["is_grasped"].to_list(), dtype=bool)
    obj = _arr(steps, "obj_pos")
    lifted = grasped & (obj[:, 2] > obj[0, 2] + rules["lift_m"])
    near = obj_goal_distance(steps) < rules["stack_near_m"]
    return {"grasp": bool(grasped.any()), "lift": bool(lifted.any()), "near target": bool(near.any()),
            "success": success}


def classify(steps: pl.DataFrame, success: bool, task: str, rules: dict) -> str:
    """``steps``: one episode's per-step log (action, is_grasped, tcp_pos, goal_pos, obj_pos)."""
    if success:
        return "Success"
    action = _arr(steps, "action")
    if len(action) < 2 or action.var(axis=0).mean() < rules["idle_variance"]:
        return "Idle"
    grasped = np.asarray(steps["is_grasped"].to_list(), dtype=bool)
    if not grasped.any():
        return "No Grasp"
    if not grasped[-1]:
        return "Drop"
    if task == "StackCube-v1":
        m = milestones(steps, success, rules)
        if m["lift"] and not m["near target"]:
            return "Grasp No Stack"
    if tcp_goal_distance(steps).min() < rules["near_miss_m"]:
        return "Near Miss"
    return "Unknown"


def classify_run(episodes: pl.DataFrame, steps: pl.DataFrame, task: str, rules: dict) -> pl.DataFrame:
    """One row per episode: its ids, failure class and (for the funnel) the milestones it reached."""
    keys = [c for c in ("exp", "checkpoint", "run", "seed") if c in episodes.columns]
    by_episode = {k: g.sort("step") for k, g in steps.group_by(keys, maintain_order=True)}  # tuple keys
    rows = []
    for ep in episodes.iter_rows(named=True):
        ep_steps = by_episode[tuple(ep[k] for k in keys)]
        rows.append({**{k: ep[k] for k in keys}, "trivial": ep["trivial"],
                     "class": classify(ep_steps, ep["success"], task, rules),
                     **milestones(ep_steps, ep["success"], rules)})
    return pl.DataFrame(rows)


def counts(classes: pl.DataFrame, include_trivial: bool = False) -> dict[str, int]:
    kept = classes if include_trivial else classes.filter(~pl.col("trivial"))
    found = dict(kept.group_by("class").len().iter_rows())
    return {c: int(found.get(c, 0)) for c in CLASSES}


def funnel(classes: pl.DataFrame) -> dict[str, int]:
    kept = classes.filter(~pl.col("trivial"))
    out = {"episodes": len(kept)}
    reached = np.ones(len(kept), dtype=bool)
    for stage in FUNNEL[1:]:
        reached &= np.asarray(kept[stage].to_list(), dtype=bool)  # a later stage counts only after earlier ones
        out[stage] = int(reached.sum())
    return out


def classify_episodes(episode_files, task: str, rules: dict, out_path) -> pl.DataFrame:
    """The classes of every episode of the given evaluation runs (each ``*.episodes.parquet`` beside its
    ``*.steps.parquet``), written to ``out_path``: the `failures` rule."""
    episodes = pl.concat([pl.read_parquet(f) for f in episode_files], how="vertical")
    steps = pl.concat([pl.read_parquet(paths.steps_beside(f)) for f in episode_files], how="vertical")
    classes = classify_run(episodes, steps, task, rules)
    with atomic_path(out_path) as tmp:
        classes.write_parquet(tmp)
    return classes
