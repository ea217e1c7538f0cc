"""The held-out evaluation pool, split: a validation pool for everything that chooses a setting (levers, tuning)
and a test pool for the tables. The test pool's sweep block is shared by every policy (it only picks each one's
checkpoint); each policy's stability runs, failure run and training-time run take their own blocks, the same for
every experiment, so rows are compared policy by policy on the same episodes."""

from __future__ import annotations

import numpy as np


def pools(evaluation_cfg: dict) -> tuple[np.ndarray, np.ndarray]:
    """(validation pool, test pool): the held-out pool's first ``validation_pool_size`` seeds, then the rest."""
    start, n, v = (evaluation_cfg[k] for k in ("seed_pool_start", "seed_pool_size", "validation_pool_size"))
    return np.arange(start, start + v), np.arange(start + v, start + n)


def _policy_blocks(evaluation_cfg: dict, replicate: int) -> dict[tuple[str, int, int], int]:
    ev = evaluation_cfg
    return {**{("stability", replicate, r): ev["stability_episodes"] for r in range(ev["stability_runs"])},
            ("failure_run", replicate, 0): ev["failure_episodes"],
            ("training_time", replicate, 0): ev["training_time_episodes"]}


def table_blocks(evaluation_cfg: dict, policies: int = 1) -> dict[tuple[str, int, int], int]:
    """(kind, replicate, run) -> episodes, for policies 0 .. ``policies`` - 1, in the order their blocks are cut from
    the shuffled test pool: the shared sweep block (replicate 0), then policy 0's blocks, then policy 1's, ... (so
    more policies move no earlier block's seeds, and one policy keeps the seeds it always had)."""
    blocks = {("sweep", 0, 0): evaluation_cfg["sweep_episodes"]}
    for replicate in range(policies):
        blocks |= _policy_blocks(evaluation_cfg, replicate)
    return blocks


def pool_problems(evaluation_cfg: dict, policies: int = 1) -> list[str]:
    """The test pool must hold every table job's block of policies 0 .. ``policies`` - 1, disjoint; the validation
    pool must leave it seeds."""
    validation, test = pools(evaluation_cfg)
    if len(test) < 1:
        return [f"  evaluation.validation_pool_size: {len(validation)} leaves no test seeds in a pool of "
                f"{evaluation_cfg['seed_pool_size']}"]
    need = sum(table_blocks(evaluation_cfg, policies).values())
    if need > len(test):
        per_policy = sum(_policy_blocks(evaluation_cfg, 0).values())
        return [f"  evaluation.seed_pool_size: the sweep ({evaluation_cfg['sweep_episodes']}) and {policies} policies' "
                f"stability, failure and training-time runs ({per_policy} each; policies up to replicate_seed_offset + "
                f"replicates) draw {need} disjoint seeds but the test pool (seed_pool_size - validation_pool_size) "
                f"holds {len(test)}"]
    return []


def policies_drawn(config: dict) -> int:
    """How many policies' blocks the configured build draws: every index below replicate_seed_offset + replicates."""
    return config["replicate_seed_offset"] + config["replicates"]
