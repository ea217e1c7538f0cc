"""One side of tests/test_replay.py in a process of its own, as evaluation and the gallery each run in theirs:

    python tests/replay_worker.py record TASK CAMERAS ACTIONS.npy STEPS.parquet
        steps an env built as evaluation builds the policy's (64 px, RGB) with the actions, keeping each step's
        action and state the way closed_loop.run writes them, until the first success;
    python tests/replay_worker.py replay TASK STEPS.parquet OUT.npz
        replays those steps in a camera-less env of the task with the original robot (evaluation.replay.replay,
        which checks every state), and saves the final state and success flag.

PhysX's results depend in their last bits on what ran in the process before (a grasp may then go another way), so
each side runs fresh, with nothing else simulated first."""

import sys

import numpy as np
import polars as pl
import torch

from ocpipe.config import validate as C
from ocpipe.evaluation import replay
from ocpipe.sim import envs

SEED = 10_001
REPO = __import__("pathlib").Path(__file__).resolve().parents[1]


def record(task: str, cameras: str, actions_file: str, out: str) -> None:
    config = C.load(REPO / "config" / "config.yaml")
    actions = np.load(actions_file)
    env = envs.make_env(task, config, cameras, 64, obs_mode="rgb")
    rows = []
    try:
        env.reset(seed=SEED)
        for t, action in enumerate(actions):
            _, _, _, _, info = env.step(torch.as_tensor(action[None]))
            rows.append({"seed": SEED, "step": t, "action": action.tolist(), "state": replay.env_state(env)})
            if bool(info["success"][0]):
                break
    finally:
        env.close()
    pl.DataFrame(rows, schema_overrides={"state": pl.List(pl.Float32)}).write_parquet(out)


def replay_file(task: str, steps_file: str, out: str) -> None:
    config = C.load(REPO / "config" / "config.yaml")
    record_ = replay.EpisodeRecord.from_steps(pl.read_parquet(steps_file), task)
    env = envs.make_env(task, config)
    try:
        result = replay.replay(env, record_)
    finally:
        env.close()
    np.savez(out, final_state=result.final_state, success=result.success, steps=result.steps)


if __name__ == "__main__":
    {"record": record, "replay": replay_file}[sys.argv[1]](*sys.argv[2:])
