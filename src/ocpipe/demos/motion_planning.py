"""Expert demonstrations from ManiSkill's motion-planning expert, in shards on disjoint seed ranges (rule
`demos_shard`; demos/merge.py joins the shards)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..util.atomic import atomic_path
from .files import DemoError, pair_json


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


def _plan(env, solve, seeds, wanted: int, bar) -> tuple[list[int], list[dict]]:
    """Plan seed after seed until ``wanted`` demos succeeded -> (their lengths, the failed seeds and why)."""
    failures: list[dict] = []
    lengths: list[int] = []
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
    return lengths, failures


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
    bar = tqdm(total=wanted, desc=f"{task} demos shard {shard}", disable=not progress)
    try:
        lengths, failures = _plan(env, MP_SOLUTIONS[task], seeds, wanted, bar)
    finally:
        bar.close()
        env.close()
    if len(lengths) < wanted:
        raise DemoError(
            f"{task} shard {shard}: only {len(lengths)}/{wanted} successful demos in seeds "
            f"{seeds.start}..{seeds.stop - 1} ({len(failures)} failed plans); raise demos.attempts_per_demo"
        )
    with atomic_path(pair_json(out_h5)) as tmp_json, atomic_path(out_h5) as tmp_h5:
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
