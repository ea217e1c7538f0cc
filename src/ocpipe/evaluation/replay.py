"""Replaying an evaluated episode exactly, from what its evaluation run recorded: the task, the reset seed and the
executed actions (``*.steps.parquet``: one row per step, ``action`` 8 floats), and, where the run recorded it, the
env state after each action (``state``), which each replayed step is checked against.

The physics (physx_cpu) is deterministic, but it is not memoryless: once the gripper touches the cube, an episode's
states depend, in their last bits and then visibly, on what the process simulated before it (PhysX's contact
bookkeeping survives a reset; its enhanced-determinism flag does not change that). Measured: the expert's episode of
PickCube seed 10001 is the same in a fresh env and after seed 10002, and leaves it at step 36 (the grasp) after seed
10003; replayed inside a test process that had simulated both tasks' episodes first, it left its recorded states at
step 36 too, and StackCube's at step 50. An evaluation job runs its episodes in one env of a fresh process, in its
episodes file's order, so:

  - the first episode of a job replays exactly in a fresh process (`replay`);
  - a run that recorded the states needs no physics at all to be shown: set each recorded state and draw it (the
    gallery does).

Cameras and the low-poly robot visuals (sim.robot_visual_keep) change only what is drawn: a camera-less env of the
task with the original robot replays the policy's env bit for bit (tests/test_replay.py, one fresh process
recording and another replaying), and costs the least."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import polars as pl


class ReplayDiverged(RuntimeError):
    """A replayed step left the env in another state than the one its evaluation recorded."""


@dataclass(frozen=True)
class EpisodeRecord:
    """What an evaluation run keeps of one episode, enough to replay it."""

    task: str
    seed: int
    actions: np.ndarray  # (n, 8) float32: the actions as executed (evaluation steps the env with float32 actions)
    states: np.ndarray | None = None  # (n, S) float32: the env state after each action; None for runs without it
    success: bool | None = None  # the episode's success flag, where known

    @classmethod
    def from_steps(cls, steps: pl.DataFrame, task: str, success: bool | None = None) -> EpisodeRecord:
        """``steps``: one episode's rows of a ``*.steps.parquet`` (any order)."""
        if steps.is_empty():
            raise ValueError(f"{task}: no steps to replay")
        seeds = steps["seed"].unique().to_list()
        if len(seeds) != 1:
            raise ValueError(f"{task}: the steps given hold {len(seeds)} episodes (seeds {sorted(seeds)[:5]}), not one")
        steps = steps.sort("step")
        if steps["step"].to_list() != list(range(len(steps))):
            raise ValueError(f"{task} episode seed {seeds[0]}: its steps are not 0..{len(steps) - 1} without gaps")
        # the recorded floats are the float32 actions widened to float64, so this cast gives them back exactly
        actions = np.asarray(steps["action"].to_list(), dtype=np.float32)
        states = np.asarray(steps["state"].to_list(), dtype=np.float32) if "state" in steps.columns else None
        return cls(task, int(seeds[0]), actions, states, success)


@dataclass(frozen=True)
class ReplayStep:
    t: int  # the action just executed (0-based): the env is now in the state after action t
    action: np.ndarray
    info: dict  # what env.step returned
    state: np.ndarray  # (S,) float32


@dataclass(frozen=True)
class Replayed:
    final_state: np.ndarray  # (S,) float32: after the last action
    success: bool  # the task's success flag after the last action
    steps: int


def env_state(env) -> np.ndarray:
    """The env's full physical state (every actor's pose and velocity, the robot's root, joint positions and
    velocities), flat, float32: what evaluation records after each step and a replay is checked against."""
    return env.unwrapped.get_state()[0].cpu().numpy().astype(np.float32, copy=False)


def replay_steps(env, record: EpisodeRecord, check: bool = True) -> Iterator[ReplayStep]:
    """Reset ``env`` with the record's seed and execute its actions one by one, yielding after each (the env is then
    in the step's state: render it, read it). ``check``: compare each state with the recorded one, bit for bit, and
    raise ReplayDiverged naming the episode and step at the first difference."""
    import torch

    if record.states is not None and len(record.states) != len(record.actions):
        raise ValueError(f"{record.task} episode seed {record.seed}: {len(record.actions)} actions but "
                         f"{len(record.states)} recorded states")
    env.reset(seed=record.seed)
    for t, action in enumerate(record.actions):
        _, _, _, _, info = env.step(torch.as_tensor(action[None]))
        state = env_state(env)
        if check and record.states is not None and not np.array_equal(state, record.states[t]):
            diff = float(np.abs(state.astype(np.float64) - record.states[t]).max()) if state.shape == \
                record.states[t].shape else float("nan")
            raise ReplayDiverged(
                f"{record.task} episode seed {record.seed}: the replay left the recorded states at step {t} of "
                f"{len(record.actions)} (largest difference {diff:.3g}; state sizes {state.shape[0]} and "
                f"{record.states[t].shape[0]}): was it evaluated with another simulator backend or ManiSkill version?")
        yield ReplayStep(t, action, info, state)


def replay(env, record: EpisodeRecord, on_step: Callable[[ReplayStep], None] | None = None,
           check: bool = True) -> Replayed:
    """Replay the whole episode (see replay_steps), calling ``on_step`` after each action, and return the final
    state and success flag. Raises ReplayDiverged where the record's success flag is not the replay's."""
    last = None
    for last in replay_steps(env, record, check):
        if on_step is not None:
            on_step(last)
    if last is None:
        raise ValueError(f"{record.task} episode seed {record.seed}: no actions to replay")
    success = bool(last.info["success"][0])
    if check and record.success is not None and success != record.success:
        raise ReplayDiverged(f"{record.task} episode seed {record.seed}: recorded success {record.success}, "
                             f"replayed {success}")
    return Replayed(last.state, success, len(record.actions))
