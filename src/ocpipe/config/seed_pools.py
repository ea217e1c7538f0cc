"""The held-out evaluation pool, split: a validation pool for everything that chooses a setting (levers, tuning)
and a test pool for the tables, whose sweep, stability runs, failure run and training-time run each take their
own block."""

from __future__ import annotations

import numpy as np


def pools(evaluation_cfg: dict) -> tuple[np.ndarray, np.ndarray]:
    """(validation pool, test pool): the held-out pool's first ``validation_pool_size`` seeds, then the rest."""
    start, n, v = (evaluation_cfg[k] for k in ("seed_pool_start", "seed_pool_size", "validation_pool_size"))
    return np.arange(start, start + v), np.arange(start + v, start + n)


def table_blocks(evaluation_cfg: dict) -> dict[tuple[str, int], int]:
    """(kind, run) -> episodes, in the order their blocks are cut from the shuffled test pool (the training-time
    run's last, so adding it moved no other block's seeds)."""
    ev = evaluation_cfg
    return {("sweep", 0): ev["sweep_episodes"],
            **{("stability", r): ev["stability_episodes"] for r in range(ev["stability_runs"])},
            ("failure_run", 0): ev["failure_episodes"], ("training_time", 0): ev["training_time_episodes"]}


def pool_problems(evaluation_cfg: dict) -> list[str]:
    """The test pool must hold every table job's block, disjoint; the validation pool must leave it seeds."""
    validation, test = pools(evaluation_cfg)
    if len(test) < 1:
        return [f"  evaluation.validation_pool_size: {len(validation)} leaves no test seeds in a pool of "
                f"{evaluation_cfg['seed_pool_size']}"]
    need = sum(table_blocks(evaluation_cfg).values())
    if need > len(test):
        return [f"  evaluation.seed_pool_size: the sweep, stability, failure and training-time runs draw {need} "
                f"disjoint seeds but the test pool (seed_pool_size - validation_pool_size) holds {len(test)}"]
    return []
