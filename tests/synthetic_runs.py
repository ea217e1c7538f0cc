"""Synthetic evaluation files for the table and findings tests: rows with known success rates, lengths and failure
classes, written where the workflow would write them (``ocpipe.study.inputs``)."""

import json
from pathlib import Path

import polars as pl

from ocpipe.config.experiments import resolve, saved_epochs
from ocpipe.paths import split_policy
from ocpipe.study import inputs, targets


def _episodes(successes: int, n: int, steps: int, run: int) -> pl.DataFrame:
    # lengths spread around ``steps`` so that rank tests have ties to break
    return pl.DataFrame({"exp": ["e"] * n, "checkpoint": [16] * n, "run": [run] * n, "seed": list(range(n)),
                         "success": [i < successes for i in range(n)], "trivial": [False] * n,
                         "steps": [steps + (i % 7) - 3 for i in range(n)], "return": [1.0] * n})


def _classes(counts: dict[str, int]) -> pl.DataFrame:
    labels = [c for c, k in counts.items() for _ in range(k)]
    return pl.DataFrame({"seed": list(range(len(labels))), "trivial": [False] * len(labels), "class": labels})


def write_rows(config, runs: Path, rows: dict) -> None:
    """Per experiment, for each of its policies (``targets.policies``): (successes per 40-episode run, mean length,
    failure-run class counts). A value is one such tuple, written for every policy, or a list of one per policy."""
    for exp, specs in rows.items():
        pids = targets.policies(config, exp)
        specs = specs if isinstance(specs, list) else [specs] * len(pids)
        assert len(specs) == len(pids), f"{exp}: {len(specs)} specs for {len(pids)} policies"
        for pid, spec in zip(pids, specs, strict=True):
            _write_policy(config, runs, pid, *spec)


def _write_policy(config, runs: Path, pid: str, per_run: list[int], steps: int, classes: dict[str, int]) -> None:
    for r, f in enumerate(inputs.STABILITY.files(config, pid, str(runs))):
        Path(f).parent.mkdir(parents=True, exist_ok=True)
        _episodes(per_run[r], 40, steps, r).write_parquet(f)
    _classes(classes).write_parquet(inputs.FAILURES.files(config, pid, str(runs))[0])
    train_seeds = inputs.TRAIN_SEEDS.files(config, pid, str(runs))[0]
    _episodes(per_run[0], 40, steps, 0).write_parquet(train_seeds)
    # a training-time run of 30 episodes with run 0's success rate (Table 5.5)
    training_time = inputs.TRAINING_TIME.files(config, pid, str(runs))[0]
    _episodes(round(per_run[0] * 30 / 40), 30, steps, 0).write_parquet(training_time)
    epochs = saved_epochs(resolve(config, split_policy(pid)[0]))
    sweep = pl.concat([_episodes(per_run[0], 6, steps, 0).with_columns(checkpoint=pl.lit(e)) for e in epochs])
    sweep.write_parquet(inputs.SWEEP.files(config, pid, str(runs))[0])
    Path(inputs.BEST.files(config, pid, str(runs))[0]).write_text(json.dumps({"epoch": epochs[-1]}))


def classes(near_miss, no_grasp, success, n=120):
    return {"Success": success, "Near Miss": near_miss, "No Grasp": no_grasp,
            "Drop": n - success - near_miss - no_grasp}
