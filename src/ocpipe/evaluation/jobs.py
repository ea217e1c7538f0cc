"""What each evaluation job runs: which checkpoint, which seeds (sweep, stability run, failure run)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import polars as pl

from ..config.seed_pools import pool_problems, pools, table_blocks
from ..frames.store import open_store
from ..util.atomic import atomic_path, write_json
from . import closed_loop

# random streams: (root seed, purpose)
TEST_POOL, VALIDATION_POOL, TRAIN_SEEDS = 1, 4, 3
TEST_KINDS = ("sweep", "stability", "failure_run")  # each draws its own block of the test pool


def seeds_for(kind: str, evaluation_cfg: dict, seed: int, run: int = 0,
              episode_seeds: list[int] | None = None) -> list[int]:
    """A table job's seeds. The sweep, stability run ``run`` and the failure run take pairwise disjoint blocks of
    one shuffle of the test pool, the same for every experiment (rows are compared on the same episodes);
    'train_seeds' are demo seeds (Table 5.6)."""
    if kind == "train_seeds":
        return training_seeds(evaluation_cfg, episode_seeds or [], seed)
    if kind not in TEST_KINDS:
        raise ValueError(f"unknown evaluation kind {kind!r}")
    problems = pool_problems(evaluation_cfg)
    if problems:
        raise ValueError(problems[0].strip())
    shuffled = np.random.default_rng([seed, TEST_POOL]).permutation(pools(evaluation_cfg)[1])
    start = 0
    for block, n in table_blocks(evaluation_cfg).items():
        if block == (kind, run if kind == "stability" else 0):
            return sorted(int(s) for s in shuffled[start:start + n])
        start += n
    raise ValueError(f"stability run {run}: evaluation.stability_runs is {evaluation_cfg['stability_runs']}")


def validation_seeds(evaluation_cfg: dict, n: int, seed: int) -> list[int]:
    """The first ``n`` seeds of one shuffle of the validation pool: for everything that chooses a setting."""
    validation = pools(evaluation_cfg)[0]
    if n > len(validation):
        raise ValueError(f"{n} validation episodes asked for but evaluation.validation_pool_size is {len(validation)}")
    return sorted(int(s) for s in np.random.default_rng([seed, VALIDATION_POOL]).permutation(validation)[:n])


def training_seeds(evaluation_cfg: dict, episode_seeds: list[int], seed: int) -> list[int]:
    """Seeds of demos the policy was trained on (Table 5.6's training-seed SR), as many as a stability run."""
    n = min(evaluation_cfg["stability_episodes"], len(episode_seeds))
    rng = np.random.default_rng([seed, TRAIN_SEEDS])
    return sorted(int(s) for s in rng.choice(np.asarray(episode_seeds), size=n, replace=False))


OPEN_LOOP_COLUMNS = ("val_joint_err_rad", "val_first_joint_err_rad", "val_gripper_agree")


def best_checkpoint(sweep_files: list[str | Path], train_log: str | Path | None = None) -> dict:
    """The checkpoint with the highest sweep SR; ties go to the lower open-loop joint error on the held-out demos
    (with ``train_log`` and held-out demos), then the higher mean return, then the later epoch.

    With ``train_log``, each sweep row also carries that epoch's open-loop error on the held-out demos, so a
    checkpoint's closed-loop SR and its open-loop error sit side by side. A sweep of a few episodes ties often
    (0/6 against 0/6), and then the open-loop error over every frame of the held-out demos says more than the mean
    return of those few episodes: in one default build the return picked goal3d's epoch 8 (0.0164 rad), which
    succeeded in 1 of 60 stability episodes, over epoch 16 (0.0138 rad), which succeeds in 16 of 100."""
    log = pl.read_parquet(train_log) if train_log else None
    rows = []
    for f in sweep_files:
        eps = pl.read_parquet(f)
        row = {"checkpoint": int(eps["checkpoint"][0]), "sr": closed_loop.success_rate(eps),
               "mean_return": float(eps["return"].mean()), "episodes": len(eps)}
        if log is not None:
            at = log.filter(pl.col("epoch") == row["checkpoint"])
            row.update({c: float(at[c][0]) for c in OPEN_LOOP_COLUMNS if c in at.columns and len(at)})
        rows.append(row)
    def rank(r):
        sr, err = r["sr"], r.get("val_joint_err_rad", float("nan"))
        return (-1.0 if math.isnan(sr) else sr, 0.0 if math.isnan(err) else -err, r["mean_return"], r["checkpoint"])

    rows.sort(key=rank)
    return {"epoch": rows[-1]["checkpoint"], "sweep": rows}


def run_job(kind: str, exp: str, config: dict, checkpoints_dir, frames, encoder_ckpt, out_episodes, out_steps,
            seed: int, run: int = 0, best_json=None, epoch: int | None = None, threads: int = 1,
            progress: bool = True, policy: dict | None = None, validation_episodes: int = 0) -> pl.DataFrame:
    """``policy``: the experiment's resolved settings; a checkpoint trained with another task, camera set,
    resolution or encoder is refused before the simulator starts. ``kind`` 'validation' (a lever) runs
    ``validation_episodes`` episodes of the validation pool."""
    if epoch is None:
        epoch = json.loads(Path(best_json).read_text())["epoch"]
    ckpt = Path(checkpoints_dir) / f"epoch_{epoch:04d}.pt"
    if not ckpt.is_file():
        raise FileNotFoundError(f"{ckpt}: experiment {exp} saved no checkpoint at epoch {epoch}")
    import torch

    from ..util.devices import pick_device

    torch.set_num_threads(threads)
    loop = closed_loop.ClosedLoop(ckpt, config, frames, encoder_ckpt or None,
                                 device=pick_device(config["evaluation"]["device"]), expected=policy)
    try:
        if kind == "validation":  # a lever: the first episodes of the validation pool's shuffle
            seeds = validation_seeds(config["evaluation"], validation_episodes, seed)
        else:
            episode_seeds = list(open_store(frames).attrs["episode_seeds"]) if kind == "train_seeds" else None
            seeds = seeds_for(kind, config["evaluation"], seed, run, episode_seeds)
        pool = {"train_seeds": "demos", "validation": "validation"}.get(kind, "test")
        ids = {"exp": exp, "checkpoint": epoch, "run": run, "kind": kind, "seed_pool": pool}
        episodes, steps = closed_loop.run(loop, seeds, ids, progress)
    finally:
        loop.close()
    with atomic_path(out_steps) as tmp:
        steps.write_parquet(tmp)
    with atomic_path(out_episodes) as tmp:
        episodes.write_parquet(tmp)
    return episodes


def write_best(sweep_files, out_json, train_log=None) -> dict:
    best = best_checkpoint(sweep_files, train_log)
    write_json(out_json, best)
    return best
