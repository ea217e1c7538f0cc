"""What each evaluation job runs: which checkpoint, which seeds (sweep, stability run, failure run, training-time
run)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl

from ..config.seed_pools import pool_problems, pools, table_blocks
from ..frames.store import open_store
from ..paths import split_policy
from ..util.atomic import atomic_path
from . import closed_loop

# random streams: (root seed, purpose)
TEST_POOL, VALIDATION_POOL, TRAIN_SEEDS = 1, 4, 3
TEST_KINDS = ("sweep", "stability", "failure_run", "training_time")  # each draws its own block of the test pool
NAMED_CHECKPOINTS = ("sweep", "validation")  # the kinds that run the checkpoints they are given; the rest the best


def seeds_for(kind: str, evaluation_cfg: dict, seed: int, run: int = 0,
              episode_seeds: list[int] | None = None, replicate: int = 0) -> list[int]:
    """A table job's seeds. The sweep, and policy ``replicate``'s stability run ``run``, failure run and
    training-time run take pairwise disjoint blocks of one shuffle of the test pool (config.seed_pools), the same
    for every experiment (rows are compared policy by policy on the same episodes); 'train_seeds' are demo seeds
    (Table 5.6)."""
    if kind == "train_seeds":
        return training_seeds(evaluation_cfg, episode_seeds or [], seed)
    if kind not in TEST_KINDS:
        raise ValueError(f"unknown evaluation kind {kind!r}")
    if kind == "stability" and not 0 <= run < evaluation_cfg["stability_runs"]:
        raise ValueError(f"stability run {run}: evaluation.stability_runs is {evaluation_cfg['stability_runs']}")
    problems = pool_problems(evaluation_cfg, replicate + 1)
    if problems:
        raise ValueError(problems[0].strip())
    shuffled = np.random.default_rng([seed, TEST_POOL]).permutation(pools(evaluation_cfg)[1])
    wanted = ("sweep", 0, 0) if kind == "sweep" else (kind, replicate, run if kind == "stability" else 0)
    start = 0
    for block, n in table_blocks(evaluation_cfg, replicate + 1).items():
        if block == wanted:
            return sorted(int(s) for s in shuffled[start:start + n])
        start += n
    raise AssertionError(f"no block {wanted}")  # table_blocks holds every kind of every policy up to replicate


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


def run_job(kind: str, exp: str, config: dict, checkpoints_dir, frames, encoder_ckpt, out_episodes, out_steps,
            seed: int, run: int = 0, best_json=None, epochs: list[int] | None = None, threads: int = 1,
            progress: bool = True, policy: dict | None = None, validation_episodes: int = 0) -> pl.DataFrame:
    """``exp``: the policy's id (paths.policy_id: its replicate picks its block of test episodes). ``policy``: the
    experiment's resolved settings; a checkpoint trained with another task, camera set, resolution or encoder is
    refused before the simulator starts. ``epochs``: the checkpoints to run, one after another on the same seeds in
    one process (a sweep, or a lever's; each row names its checkpoint); every other kind runs ``best_json``'s alone,
    and is refused a list. ``kind`` 'validation' (a lever) runs ``validation_episodes`` episodes of the validation
    pool."""
    if kind in NAMED_CHECKPOINTS:
        if not epochs:
            raise ValueError(f"a {kind} job of {exp} needs the checkpoints it runs (epochs), got {epochs!r}")
    elif epochs is not None or best_json is None:
        raise ValueError(f"a {kind} job of {exp} runs its best checkpoint alone: it takes best_json "
                         f"({best_json}), not a list of checkpoints (epochs {epochs})")
    else:
        epochs = [json.loads(Path(best_json).read_text())["epoch"]]
    ckpts = [Path(checkpoints_dir) / f"epoch_{e:04d}.pt" for e in epochs]
    for epoch, ckpt in zip(epochs, ckpts, strict=True):
        if not ckpt.is_file():
            raise FileNotFoundError(f"{ckpt}: experiment {exp} saved no checkpoint at epoch {epoch}")
    import torch

    from ..util.devices import pick_device

    torch.set_num_threads(threads)
    if kind == "validation":  # a lever: the first episodes of the validation pool's shuffle
        seeds = validation_seeds(config["evaluation"], validation_episodes, seed)
    else:
        episode_seeds = list(open_store(frames).attrs["episode_seeds"]) if kind == "train_seeds" else None
        seeds = seeds_for(kind, config["evaluation"], seed, run, episode_seeds, split_policy(exp)[1])
    pool = {"train_seeds": "demos", "validation": "validation"}.get(kind, "test")
    device = pick_device(config["evaluation"]["device"])
    episode_frames, step_frames, first = [], [], None
    for epoch, ckpt in zip(epochs, ckpts, strict=True):
        # a new simulator for each checkpoint, as a job of its own would build: the physics engine keeps contact
        # state across resets, so an episode run after others can differ from a fresh one in round-off. The job's
        # start-up that is saved is the imports, not the simulator.
        loop = closed_loop.ClosedLoop(ckpt, config, frames, encoder_ckpt or None, device=device, expected=policy)
        try:
            if first is not None and loop.policy != first:
                raise ValueError(f"{ckpt}: a checkpoint of another policy than {ckpts[0]} (its settings differ)")
            first = loop.policy
            ids = {"exp": exp, "checkpoint": epoch, "run": run, "kind": kind, "seed_pool": pool}
            episodes, steps = closed_loop.run(loop, seeds, ids, progress)
        finally:
            loop.close()
        episode_frames.append(episodes)
        step_frames.append(steps)
    episodes, steps = pl.concat(episode_frames), pl.concat(step_frames)
    with atomic_path(out_steps) as tmp:
        steps.write_parquet(tmp)
    with atomic_path(out_episodes) as tmp:
        episodes.write_parquet(tmp)
    return episodes
