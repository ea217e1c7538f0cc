"""An evaluated episode drawn for people: each step's env state set on two environments, a viewer (ManiSkill's
human render camera on the original robot, sim.envs.make_viewer_env) and the policy's own (evaluation.closed_loop
.policy_env: its camera set, resolution, shader and low-poly robot), and drawn by both. No physics runs here.

The states come from the run's record (steps file, ``state``); a run recorded before states were kept is refused
with a clear error, to be evaluated again. Setting a state draws the policy's cameras as its evaluation saw them up
to the link poses' last float bits: a robot link's pose is computed from the joint positions here and integrated
there, so a pixel on an outline may differ now and then (measured: one pixel, by 2/255, in 2 of 162 frames)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np
import polars as pl
import torch

from ..evaluation import closed_loop, replay
from ..policy.settings import PolicySettings
from ..sim import envs


class Views:
    """The viewer env and the policy's env of one experiment, drawing states set on them."""

    def __init__(self, policy: dict, config: dict, resolution: int, shader: str):
        settings = PolicySettings.of(policy)
        self.task = settings.stores.task
        self.reads_labels = settings.stores.encoder == "state"  # the control renders no camera, as evaluated
        names = envs.CAMERA_SETS[settings.stores.cams]
        self.camera_names = [] if self.reads_labels else [names[i] for i in settings.stores.cameras]
        self.viewer = envs.make_viewer_env(self.task, config, resolution, shader)
        self.policy_env = None if self.reads_labels else closed_loop.policy_env(settings, config, False)

    def close(self) -> None:
        self.viewer.close()
        if self.policy_env is not None:
            self.policy_env.close()

    def _draw(self, obs) -> tuple[np.ndarray, list[np.ndarray]]:
        viewer = self.viewer.render()[0].cpu().numpy()
        if self.policy_env is None:
            return viewer, []
        data = obs["sensor_data"]
        return viewer, [data[envs.SIM_CAMERA_UID[c]]["rgb"][0].cpu().numpy() for c in self.camera_names]

    def reset(self, seed: int) -> tuple[np.ndarray, list[np.ndarray]]:
        """The episode's first frame: both envs reset with its seed (viewer image, the policy's images)."""
        self.viewer.reset(seed=seed)
        obs = self.policy_env.reset(seed=seed)[0] if self.policy_env is not None else None
        return self._draw(obs)

    def show(self, state: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Both envs set to ``state`` (a recorded env state) and drawn."""
        batch = torch.from_numpy(np.asarray(state, dtype=np.float32)[None])
        self.viewer.unwrapped.set_state(batch)
        obs = None
        if self.policy_env is not None:
            self.policy_env.unwrapped.set_state(batch)
            obs = self.policy_env.unwrapped.get_obs()
        return self._draw(obs)

    def frames(self, record: replay.EpisodeRecord, wanted: Iterable[int]) -> Iterator[tuple[int, np.ndarray,
                                                                                           list[np.ndarray]]]:
        """(k, viewer image, the policy's images) of frames ``wanted`` (k: the env after k actions, 0..n)."""
        if record.states is None:
            raise ValueError(f"{record.task} episode seed {record.seed}: no recorded states to draw")
        for k in sorted(set(wanted)):
            if not 0 <= k <= len(record.actions):
                raise ValueError(f"frame {k} of an episode of {len(record.actions)} steps")
            yield (k, *(self.reset(record.seed) if k == 0 else self.show(record.states[k - 1])))


def drawn_frames(steps: int, stride: int, extra: Iterable[int] = ()) -> list[int]:
    """The frames a video of an episode of ``steps`` actions draws: every ``stride``-th from the reset, the last
    (the env after the last action) and ``extra`` (a contact sheet's)."""
    if stride < 1:
        raise ValueError(f"gallery.frame_stride must be at least 1, got {stride}")
    return sorted({*range(0, steps + 1, stride), steps, *extra})


def recorded_episodes(task: str, episodes: pl.DataFrame, steps: pl.DataFrame, wanted: set[int],
                      source: str) -> dict[int, replay.EpisodeRecord]:
    """Seed -> the record of each episode in ``wanted`` (seeds) of one evaluation run (its episodes and steps files;
    ``source`` names the episodes file in errors), with the state its evaluation recorded after every step."""
    order = episodes["seed"].to_list()
    missing = wanted - set(order)
    if missing:
        raise ValueError(f"{source}: seeds {sorted(missing)} are not episodes of this run")
    if "state" not in steps.columns:
        # replaying for the states would need each run's episodes in a fresh process, in their order (see
        # evaluation.replay): rerunning the evaluation costs about the same and keeps one way to draw
        raise ValueError(f"{source}: its steps file has no 'state' column (evaluated before env states were "
                         "recorded); rerun this evaluation (snakemake --forcerun on it) to draw its episodes")
    by_seed = {key[0]: group for key, group in steps.group_by(["seed"], maintain_order=True)}
    success = dict(zip(order, episodes["success"].to_list()))
    return {s: replay.EpisodeRecord.from_steps(by_seed[s], task, success[s]) for s in sorted(wanted)}
