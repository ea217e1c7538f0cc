"""An evaluated episode replays exactly from its record (evaluation/replay.py): on both tasks, an episode recorded the
way evaluation records it (the policy's env: cameras, low-poly robot visuals, float32 actions, the state after each
step), by a process of its own, replays in another fresh process, in a camera-less env, to the same states, bit for
bit, and the same success flag (tests/replay_worker.py). The actions are the motion-planning expert's (succeeding)
and the same with the gripper held open (failing)."""

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import polars as pl
import pytest

from ocpipe import paths
from ocpipe.evaluation import replay
from ocpipe.sim import envs

SEED = 10_001  # a held-out pool seed, as evaluation uses; the expert solves it on both tasks (replay_worker's too)
WORKER = Path(__file__).parent / "replay_worker.py"
TASKS = {"PickCube-v1": "dual", "StackCube-v1": "native"}  # each task with a camera set the study evaluates it on


class ActionRecorder(gym.Wrapper):
    """Keeps the actions the expert steps the env with."""

    def reset(self, **kwargs):
        self.actions = []
        return self.env.reset(**kwargs)

    def step(self, action):
        self.actions.append(np.asarray(action, dtype=np.float32).reshape(-1))
        return self.env.step(action)


def expert_actions(task: str, config: dict) -> np.ndarray:
    from mani_skill.examples.motionplanning.panda.run import MP_SOLUTIONS

    env = ActionRecorder(envs.make_env(task, config))
    try:
        result = MP_SOLUTIONS[task](env, seed=SEED, debug=False, vis=False)
    finally:
        env.close()
    assert result != -1 and bool(result[-1]["success"][0]), f"the expert does not solve {task} seed {SEED}"
    return np.stack(env.actions)


def run_worker(*args) -> None:
    proc = subprocess.run([sys.executable, str(WORKER), *map(str, args)], capture_output=True, text=True)
    assert proc.returncode == 0, f"replay_worker {args[0]} failed:\n{proc.stderr[-3000:]}"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Each task's expert episode and the same with the gripper held open, each recorded by a fresh process (as an
    evaluation job records its episodes): task -> outcome -> its steps file."""
    from conftest import REPO

    from ocpipe.config import validate as C

    config = C.load(REPO / "config" / "config.yaml")
    folder = tmp_path_factory.mktemp("replay")
    out = {}
    for task, cameras in TASKS.items():
        actions = expert_actions(task, config)
        held_open = actions.copy()
        held_open[:, 7] = 1.0  # the gripper command: +1 open, so nothing is ever grasped
        out[task] = {}
        for outcome, acts in (("succeeds", actions), ("fails", held_open)):
            np.save(folder / f"{task}_{outcome}.npy", acts)
            out[task][outcome] = folder / f"{task}_{outcome}.steps.parquet"
            run_worker("record", task, cameras, folder / f"{task}_{outcome}.npy", out[task][outcome])
    return config, out


@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize("outcome", ["succeeds", "fails"])
def test_an_evaluated_episode_replays_to_the_same_state_and_success(recorded, task, outcome, tmp_path):
    _, files = recorded
    steps = pl.read_parquet(files[task][outcome])
    run_worker("replay", task, files[task][outcome], tmp_path / "replayed.npz")
    result = np.load(tmp_path / "replayed.npz")
    assert bool(result["success"]) == (outcome == "succeeds")
    assert int(result["steps"]) == len(steps)
    # exact: the same float32 actions through the same deterministic physics (physx_cpu) in a fresh process; every
    # intermediate state was checked the same way inside replay()
    np.testing.assert_array_equal(result["final_state"], np.asarray(steps["state"][-1].to_list(), np.float32))


def test_a_replay_that_leaves_the_recorded_states_or_success_names_the_episode_and_step(recorded):
    config, files = recorded
    task = "PickCube-v1"
    record = replay.EpisodeRecord.from_steps(pl.read_parquet(files[task]["succeeds"]), task)
    nudged = record.actions.copy()
    nudged[5, 0] += 0.05  # one joint target moved at step 5, long before any contact
    held_open = replay.EpisodeRecord.from_steps(pl.read_parquet(files[task]["fails"]), task, success=True)
    env = envs.make_env(task, config)
    seen = []
    try:
        with pytest.raises(replay.ReplayDiverged, match=f"seed {SEED}: .* at step 5 of"):
            replay.replay(env, replay.EpisodeRecord(task, SEED, nudged, record.states))
        with pytest.raises(replay.ReplayDiverged, match="recorded success True, replayed False"):
            replay.replay(env, held_open, on_step=lambda s: seen.append(s.t))
    finally:
        env.close()
    assert seen == list(range(len(held_open.actions)))


def test_a_record_must_be_one_whole_episode():
    steps = pl.DataFrame({"seed": [1, 1, 2], "step": [0, 1, 0], "action": [[0.0] * 8] * 3})
    with pytest.raises(ValueError, match="hold 2 episodes"):
        replay.EpisodeRecord.from_steps(steps, "PickCube-v1")
    with pytest.raises(ValueError, match="not 0..1 without gaps"):
        replay.EpisodeRecord.from_steps(steps.filter(pl.col("seed") == 1).with_columns(step=pl.Series([0, 2])),
                                        "PickCube-v1")
    record = replay.EpisodeRecord.from_steps(steps.filter(pl.col("seed") == 1).reverse(), "PickCube-v1")
    assert record.states is None and record.actions.dtype == np.float32 and record.actions.shape == (2, 8)


def test_the_first_episode_an_evaluation_job_recorded_replays_in_a_fresh_process(tiny_run, tmp_path):
    """The closed loop's own record, not this file's copy of it: the first episode of one of the tiny run's stability
    jobs (the first its env simulated), replayed in a fresh process, reaches its recorded states and success."""
    episodes_file = sorted((tiny_run / "results" / "runs").glob("goal2d*/stability/run_0.episodes.parquet"))[0]
    first = pl.read_parquet(episodes_file).row(0, named=True)
    steps = pl.read_parquet(tiny_run / paths.steps_beside(episodes_file)).filter(pl.col("seed") == first["seed"])
    steps.write_parquet(tmp_path / "first.steps.parquet")
    run_worker("replay", "PickCube-v1", tmp_path / "first.steps.parquet", tmp_path / "replayed.npz")
    result = np.load(tmp_path / "replayed.npz")
    assert bool(result["success"]) == first["success"] and int(result["steps"]) == first["steps"] == len(steps)
    # exact: as above; replay() checked every intermediate state the same way
    np.testing.assert_array_equal(result["final_state"], np.asarray(steps.sort("step")["state"][-1].to_list(),
                                                                    np.float32))
