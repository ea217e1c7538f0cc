"""What a table row reads of each of its K policies, each input declared once: its name, the files it is read from
(under results/runs/{policy}/, ocpipe.paths) and how a row's files become the row's data. Tables, figures and
findings name the inputs they need (registry, findings); the workflow asks for exactly those files (targets)."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from .. import paths

EPISODES = paths.EPISODES


@dataclass(frozen=True)
class Input:
    name: str  # what an input is compared, hashed and pickled by (INPUTS)
    locate: Callable[[dict, str, str], list[str]] = field(compare=False)  # (config, policy id, runs dir) -> files
    load: Callable[[dict[int, list[str]]], object] = field(compare=False)  # the row's {replicate: files} -> its data

    def files(self, config: dict, pid: str, runs_dir: str = paths.RUNS) -> list[str]:
        """The files holding this input of policy ``pid`` (a policy id, or an experiment's name: its policy 0)."""
        return self.locate(config, pid, str(runs_dir))

    def __repr__(self) -> str:
        return self.name

    def __reduce__(self):
        return _declared, (self.name,)


def _declared(name: str) -> Input:
    return INPUTS[name]


def _frame(per_policy: dict[int, list[str]]) -> pl.DataFrame:
    """Episodes, logs or failure classes of the row's policies as one frame with a ``policy`` column."""
    return pl.concat([pl.concat([pl.read_parquet(f) for f in files], how="vertical").with_columns(policy=pl.lit(k))
                      for k, files in per_policy.items()], how="vertical")


def _best(per_policy: dict[int, list[str]]) -> list[dict]:
    """Each policy's chosen checkpoint (best.json) with its sweep summary."""
    return [{**json.loads(Path(files[0]).read_text()), "policy": k} for k, files in per_policy.items()]


def _model_facts(per_policy: dict[int, list[str]]) -> dict:
    """The model's size, once for the row: every policy of a row has the same architecture."""
    import torch

    checkpoints_dir = Path(next(iter(per_policy.values()))[0])
    last = sorted(checkpoints_dir.glob("epoch_*.pt"))[-1]
    ckpt = torch.load(last, map_location="cpu", weights_only=False)
    # the trainable parameters, counted by the training that owned the model (the state dict also holds the
    # Normalizer's statistics and a frozen read-out's weights); None in a checkpoint from before it was recorded
    return {"parameters": ckpt.get("parameters"), "sequence_length": int(ckpt["model"]["pos"].shape[0]),
            "checkpoint": str(last)}


def _one(pattern: str) -> Callable[[dict, str, str], list[str]]:
    return lambda config, pid, runs_dir: [paths.in_runs(pattern, runs_dir, exp=pid)]


def _stability_files(config: dict, pid: str, runs_dir: str) -> list[str]:
    return [paths.in_runs(paths.STABILITY, runs_dir, exp=pid, run=r) + EPISODES
            for r in range(config["evaluation"]["stability_runs"])]


STABILITY = Input("stability", _stability_files, _frame)  # the stability runs' episodes
SWEEP = Input("sweep", _one(paths.SWEEP + EPISODES), _frame)  # every saved checkpoint's sweep episodes
FAILURES = Input("failures", _one(paths.FAILURES), _frame)  # the failure classes of the classified episodes
TRAIN_LOG = Input("train_log", _one(paths.TRAIN_LOG), _frame)  # per-epoch losses and seconds
CHECKPOINTS = Input("checkpoints", _one(paths.CHECKPOINTS), _model_facts)  # the model's size
TRAIN_SEEDS = Input("train_seeds", _one(paths.TRAIN_SEEDS + EPISODES), _frame)  # episodes on demo seeds
BEST = Input("best", _one(paths.BEST), _best)  # the chosen checkpoint
TRAINING_TIME = Input("training_time", _one(paths.TRAINING_TIME + EPISODES), _frame)  # Table 5.5's one run
INPUTS = {i.name: i for i in (STABILITY, SWEEP, FAILURES, TRAIN_LOG, CHECKPOINTS, TRAIN_SEEDS, BEST, TRAINING_TIME)}
