"""Expert demonstrations: motion-planning shards on disjoint seed ranges, merging, and importing official files.

Every demo set is a ManiSkill-format pair ``<name>.h5`` + ``<name>.json`` whose episodes are listed in the
json in numeric ``episode_id`` order, each with its ``episode_seed``."""

from __future__ import annotations

import json
import logging
import re
import shutil
from pathlib import Path

import h5py
import numpy as np
from tqdm import tqdm

from ..util.atomic import atomic_path, write_json

log = logging.getLogger(__name__)


class DemoError(RuntimeError):
    pass


def shard_seed_range(config: dict, shard: int) -> tuple[range, int]:
    """(seeds this shard may try, demos it must deliver). Shards own disjoint consecutive seed blocks, so
    merged sets never repeat a seed (ManiSkill's --num-procs can)."""
    d = config["demos"]
    n_shards, total = d["shards"], d["num_demos"]
    if not 0 <= shard < n_shards:
        raise DemoError(f"shard {shard} out of range: demos.shards is {n_shards}")
    wanted = [total // n_shards + (1 if i < total % n_shards else 0) for i in range(n_shards)]
    start = d["seed_start"] + d["attempts_per_demo"] * sum(wanted[:shard])
    return range(start, start + d["attempts_per_demo"] * wanted[shard]), wanted[shard]


def _json_path(h5_path: str | Path) -> Path:
    return Path(h5_path).with_suffix(".json")


def generate_shard(task: str, config: dict, shard: int, out_h5: str | Path, progress: bool = True) -> dict:
    """Run ManiSkill's motion-planning expert over this shard's seeds until it has its demos; failed plans are
    skipped to the next seed and counted. Writes out_h5 + .json atomically and returns a report."""
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401
    from mani_skill.examples.motionplanning.panda.run import MP_SOLUTIONS
    from mani_skill.utils.wrappers.record import RecordEpisode

    seeds, wanted = shard_seed_range(config, shard)
    sim = config["sim"]
    out_h5 = Path(out_h5)
    work = out_h5.parent / f".{out_h5.stem}.work"
    shutil.rmtree(work, ignore_errors=True)
    env = gym.make(
        task, obs_mode="none", control_mode=sim["control_mode"], sim_backend=sim["backend"], render_mode=None,
        max_episode_steps=sim["episode_cap"], sensor_configs=dict(shader_pack=sim["shader"]),
    )
    env = RecordEpisode(env, output_dir=str(work), trajectory_name="shard", save_video=False,
                        source_type="motionplanning", source_desc="ManiSkill motion-planning expert (ocpipe shard)",
                        record_reward=False, save_on_reset=False)
    solve = MP_SOLUTIONS[task]
    failures: list[dict] = []
    lengths: list[int] = []
    bar = tqdm(total=wanted, desc=f"{task} demos shard {shard}", disable=not progress)
    for seed in seeds:
        if len(lengths) == wanted:
            break
        try:
            res = solve(env, seed=seed, debug=False, vis=False)
            reason = "no motion plan" if res == -1 else None
        except Exception as exc:  # the planner raises on unreachable grasps; that is a failed plan, not a crash
            res, reason = -1, f"planner error: {exc}"
        if reason is None and not bool(res[-1]["success"].item()):
            reason = "plan executed but task not solved"
        if reason is not None:
            failures.append({"seed": seed, "reason": reason})
            env.flush_trajectory(save=False)
            continue
        env.flush_trajectory(save=True)
        lengths.append(int(res[-1]["elapsed_steps"].item()))
        bar.update(1)
        bar.set_postfix(failed=len(failures))
    bar.close()
    env.close()
    if len(lengths) < wanted:
        raise DemoError(
            f"{task} shard {shard}: only {len(lengths)}/{wanted} successful demos in seeds "
            f"{seeds.start}..{seeds.stop - 1} ({len(failures)} failed plans); raise demos.attempts_per_demo"
        )
    with atomic_path(_json_path(out_h5)) as tmp_json, atomic_path(out_h5) as tmp_h5:
        shutil.move(work / "shard.h5", tmp_h5)
        shutil.move(work / "shard.json", tmp_json)
    shutil.rmtree(work, ignore_errors=True)
    return {
        "task": task,
        "shard": shard,
        "seeds_tried": len(lengths) + len(failures),
        "demos": len(lengths),
        "failed_plans": failures,
        "mean_length": float(np.mean(lengths)),
        "max_length": int(np.max(lengths)),
    }


def _regenerate(path: str | Path) -> str:
    """What to do about a damaged demo set (path: its .h5 or its .json)."""
    p = Path(path)
    return (
        f"delete {p.with_suffix('.h5').name} and {p.with_suffix('.json').name} and rerun the workflow to "
        "regenerate them (an imported demo set: copy it again from its source)"
    )


def episodes(json_path: str | Path) -> list[dict]:
    """The json's episodes sorted numerically by episode_id (h5 keys sort traj_0, traj_1, traj_10, ...)."""
    try:
        meta = json.loads(Path(json_path).read_text())
    except json.JSONDecodeError as exc:
        raise DemoError(
            f"{json_path}: not valid JSON ({exc}); the file is truncated or corrupt: {_regenerate(json_path)}"
        ) from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("episodes"), list):
        raise DemoError(f"{json_path}: no 'episodes' list, so not a ManiSkill demo json: {_regenerate(json_path)}")
    eps = sorted(meta["episodes"], key=lambda e: int(e["episode_id"]))
    for ep in eps:
        if "episode_seed" not in ep:
            raise DemoError(f"{json_path}: episode {ep['episode_id']} has no episode_seed")
    return eps


def open_h5(path: str | Path) -> h5py.File:
    """Open a demo .h5 for reading; a truncated or corrupt file is a DemoError that names it."""
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise DemoError(
            f"{path}: not a readable HDF5 file ({exc}); it is truncated or corrupt: {_regenerate(path)}"
        ) from exc


def check_pair(h5_path: str | Path) -> list[dict]:
    """The episodes of the demo set ``<name>.h5`` + ``<name>.json`` after checking that the .h5 opens and holds
    exactly one ``traj_<id>`` per episode the .json lists (a pair from different runs, or a copy cut short, would
    otherwise lose or mix up episodes silently)."""
    h5_path = Path(h5_path)
    json_path = _json_path(h5_path)
    for p in (h5_path, json_path):
        if not p.is_file():
            raise DemoError(f"{p}: file not found; a demo set is a .h5 and a .json of the same name: {_regenerate(p)}")
    eps = episodes(json_path)
    with open_h5(h5_path) as h5:
        try:
            keys = {k for k in h5.keys() if _TRAJ_KEY.match(k)}
        except (OSError, KeyError, RuntimeError) as exc:
            raise DemoError(
                f"{h5_path}: its list of trajectories cannot be read ({exc}); the file is corrupt: "
                f"{_regenerate(h5_path)}"
            ) from exc
    listed = {f"traj_{ep['episode_id']}" for ep in eps}
    if keys != listed:

        def some(names):
            return ", ".join(sorted(names, key=lambda k: int(k[5:]))[:5]) + (" ..." if len(names) > 5 else "")

        parts = [f"the json lists {len(eps)} episodes, the h5 holds {len(keys)} trajectories"]
        if listed - keys:
            parts.append(f"missing from the h5: {some(listed - keys)}")
        if keys - listed:
            parts.append(f"not in the json: {some(keys - listed)}")
        raise DemoError(
            f"{h5_path} does not match {json_path} ({'; '.join(parts)}): the two files come from "
            f"different runs or one was cut short: {_regenerate(h5_path)}"
        )
    return eps


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


def unreadable_error(h5_path: str | Path, key: str, exc: Exception | None = None) -> DemoError:
    why = f" ({exc})" if exc is not None else ""
    return DemoError(
        f"{h5_path}: episode {key.removeprefix('traj_')} ({key}) cannot be read{why}; the file is "
        f"corrupt: {_regenerate(h5_path)}"
    )


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
    with atomic_path(_json_path(out_h5)) as tmp_json, atomic_path(out_h5) as tmp_h5:
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


_TRAJ_KEY = re.compile(r"traj_(\d+)$")


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
    with atomic_path(_json_path(out_h5)) as tmp_json, atomic_path(out_h5) as tmp_h5:
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
