"""The demo set of a task: motion-planning shards merged into one (rule `demos_merge`), or an official ManiSkill
demo file imported into our layout (rule `demos_import`)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
from tqdm import tqdm

from ..util.atomic import atomic_path, write_json
from .files import DemoError, check_pair, episodes, open_h5, pair_json, unreadable_error


def _readable(h5: h5py.File, key: str) -> bool:
    try:
        h5[key].visititems(lambda _, obj: obj[()] if isinstance(obj, h5py.Dataset) else None)
    except (OSError, KeyError, RuntimeError, ValueError):
        return False
    return True


def first_unreadable(h5_path: str | Path) -> str | None:
    """The first trajectory of a demo .h5 whose data cannot be read, or None (reads every dataset)."""
    with open_h5(h5_path) as h5:
        return next((key for key in h5 if not _readable(h5, key)), None)


def merge(
    shard_h5s: list[str | Path],
    out_h5: str | Path,
    shard_reports: list[dict] | None = None,
    report_path: str | Path | None = None,
) -> dict:
    """Concatenate shard files in the given order into one demo set with episode ids 0..N-1."""
    from mani_skill.trajectory.merge_trajectory import merge_trajectories

    out_h5 = Path(out_h5)
    seeds = [ep["episode_seed"] for p in shard_h5s for ep in check_pair(p)]
    dup = sorted({s for s in seeds if seeds.count(s) > 1})
    if dup:
        raise DemoError(f"duplicate episode seeds across shards: {dup[:10]}")
    with atomic_path(pair_json(out_h5)) as tmp_json, atomic_path(out_h5) as tmp_h5:
        try:
            merge_trajectories(str(tmp_h5), [str(p) for p in shard_h5s], recompute_id=True)  # writes tmp_json too
        except (OSError, KeyError, RuntimeError) as exc:
            # h5py's read errors do not say which shard: find the damaged trajectory (a full disk is not one)
            for p in shard_h5s:
                key = first_unreadable(p)
                if key is not None:
                    raise unreadable_error(p, key, exc) from exc
            raise
        assert tmp_h5.with_suffix(".json") == tmp_json
    report = {"episodes": len(seeds), "seed_min": min(seeds), "seed_max": max(seeds)}
    if shard_reports:
        report["failed_plans"] = sum(len(r["failed_plans"]) for r in shard_reports)
        report["seeds_tried"] = sum(r["seeds_tried"] for r in shard_reports)
        report["failed_plan_rate"] = report["failed_plans"] / report["seeds_tried"]
        report["shards"] = shard_reports
    if report_path:
        write_json(report_path, report)
    return report


def import_official(src_h5: str | Path, src_json: str | Path, out_h5: str | Path, config: dict, task: str) -> dict:
    """Copy an official ManiSkill demo file into our layout: numeric episode order, ids renumbered 0..N-1, the
    first demos.num_demos episodes, actions in pd_joint_pos.

    Non-absolute joint control is converted to absolute joint targets read from the next recorded state's arm
    joints (the gripper command is kept); the frames stage's env-state replay then checks the result."""
    src_h5, src_json = Path(src_h5), Path(src_json)
    for p, key in ((src_h5, "h5"), (src_json, "json")):
        if not p.is_file():
            raise DemoError(f"demos.import.{task}.{key}: file not found: {p}")
    meta = json.loads(src_json.read_text())
    env_id = meta.get("env_info", {}).get("env_id")
    if env_id != task:
        raise DemoError(f"{src_json}: env_id is {env_id!r}, expected {task!r}")
    eps = episodes(src_json)[: config["demos"]["num_demos"]]
    pool = config["evaluation"]["seed_pool_start"]
    clash = [ep["episode_seed"] for ep in eps if ep["episode_seed"] >= pool]
    if clash:
        raise DemoError(f"{src_json}: episode seeds {clash[:5]} fall in the held-out pool (>= {pool})")
    out_h5 = Path(out_h5)
    out_eps = []
    with atomic_path(pair_json(out_h5)) as tmp_json, atomic_path(out_h5) as tmp_h5:
        with open_h5(src_h5) as src, h5py.File(tmp_h5, "w") as dst:
            for new_id, ep in enumerate(tqdm(eps, desc=f"import {task}")):
                key = f"traj_{ep['episode_id']}"
                if key not in src:
                    raise DemoError(f"{src_h5}: episode {ep['episode_id']} listed in the json but {key} is missing")
                try:
                    src.copy(key, dst, f"traj_{new_id}")
                except (OSError, KeyError, RuntimeError) as exc:
                    if not _readable(src, key):
                        raise unreadable_error(src_h5, key, exc) from exc
                    raise
                mode = ep.get("control_mode", meta.get("env_info", {}).get("env_kwargs", {}).get("control_mode"))
                if mode != "pd_joint_pos":
                    _to_absolute_joint_actions(dst[f"traj_{new_id}"], key)
                out_eps.append({**ep, "episode_id": new_id, "control_mode": "pd_joint_pos"})
        meta["episodes"] = out_eps
        meta.setdefault("env_info", {}).setdefault("env_kwargs", {})["control_mode"] = "pd_joint_pos"
        tmp_json.write_text(json.dumps(meta, indent=2))
    return {"episodes": len(out_eps), "source": str(src_h5)}


def _to_absolute_joint_actions(group: h5py.Group, key: str) -> None:
    arts = group.get("env_states/articulations")
    if arts is None or len(arts) == 0:
        raise DemoError(f"{key}: no env_states/articulations recorded; cannot convert actions to pd_joint_pos")
    robot = arts[sorted(arts)[0]][()]  # (T+1, 13 + 2 * dof): root pose/vel, then qpos, then qvel
    dof = (robot.shape[1] - 13) // 2
    qpos_next = robot[1:, 13 : 13 + dof]
    actions = group["actions"][()]
    absolute = np.concatenate([qpos_next[:, :7], actions[:, -1:]], axis=1).astype(np.float32)
    del group["actions"]
    group.create_dataset("actions", data=absolute)
