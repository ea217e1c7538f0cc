"""Replaying expert demos with env-state alignment and rendering the study's cameras at every step.

Each step t sets the recorded state s_t, renders the cameras and reads the labels, then applies action a_t from
that state. Nothing stops at ManiSkill's 50-step limit (the env has no TimeLimit), and because every step starts
from the recorded state, open-loop drift cannot accumulate. Replay success is the task's success flag after the
last action, as in ManiSkill's own replay tool."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import torch

from ..demos.files import episodes, unreadable_error
from ..sim import envs, projection


@dataclass
class EpisodeFrames:
    episode_id: int
    seed: int
    success: bool
    max_state_error: float  # largest |simulated s_{t+1} - recorded s_{t+1}| over the episode (diagnostic)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)


def _read_group(group: h5py.Group) -> dict:
    return {k: _read_group(v) if isinstance(v, h5py.Group) else v[()] for k, v in group.items()}


def index_state(states: dict, t: int) -> dict:
    """The recorded env state of step ``t`` (a batch of one), as set_state_dict takes it."""
    return {k: index_state(v, t) if isinstance(v, dict) else torch.from_numpy(v[t : t + 1]) for k, v in states.items()}


def _flat_state(states: dict, t: int) -> np.ndarray:
    return np.concatenate([
        _flat_state(v, t) if isinstance(v, dict) else v[t].ravel() for _, v in sorted(states.items())
    ])


def _flat_current(env, like: dict) -> np.ndarray:
    cur = env.unwrapped.get_state_dict()

    def walk(c, ref):
        return np.concatenate([
            walk(c[k], ref[k]) if isinstance(ref[k], dict) else c[k][0].cpu().numpy().ravel() for k in sorted(ref)
        ])

    return walk(cur, like)


def read_episode(h5: h5py.File, episode: dict) -> tuple[np.ndarray, dict]:
    """(actions, recorded env states) of one episode; a damaged trajectory is a DemoError naming file and episode."""
    key = f"traj_{episode['episode_id']}"
    if key not in h5:
        raise KeyError(f"episode {episode['episode_id']}: {key} missing from {h5.filename}")
    try:
        return h5[key]["actions"][()], _read_group(h5[key]["env_states"])
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        raise unreadable_error(h5.filename, key, exc) from exc


class Replayer:
    """Owns one rendering environment (physx_cpu allows one per process) for a (task, camera set, resolution)."""

    def __init__(self, task: str, config: dict, camera_set: str, resolution: int):
        self.task, self.camera_set, self.resolution = task, camera_set, resolution
        self.cameras = list(envs.CAMERA_SETS[camera_set])
        self.uids = [envs.SIM_CAMERA_UID[c] for c in self.cameras]
        # segmentation rides along in the same render pass; the encoder stage scores slot masks against it
        self.env = envs.make_env(task, config, camera_set, resolution, obs_mode="rgb+segmentation")
        self.segmentation_ids = {int(i): obj.name for i, obj in self.env.unwrapped.segmentation_id_map.items()}
        self.approx_K, self.approx_E = envs.approx_camera_matrices(config, self.cameras, resolution)

    def close(self) -> None:
        self.env.close()

    def replay(self, h5: h5py.File, episode: dict) -> EpisodeFrames:
        u = self.env.unwrapped
        actions, states = read_episode(h5, episode)
        reset_kwargs = dict(episode.get("reset_kwargs") or {})
        reset_kwargs["seed"] = episode["episode_seed"]
        self.env.reset(**reset_kwargs)
        rows: dict[str, list] = {
            k: []
            for k in (
                "rgb",
                "seg",
                "qpos",
                "tcp_pos",
                "obj_pos",
                "obj_quat",
                "goal_pos",
                "is_grasped",
                "cam_intrinsic",
                "cam_extrinsic",
            )
        }
        max_err, info = 0.0, {}
        for t, action in enumerate(actions):
            u.set_state_dict(index_state(states, t))
            sensors = u._get_obs_sensor_data()
            params = u.get_sensor_params()
            rows["rgb"].append(np.stack([sensors[uid]["rgb"][0].cpu().numpy() for uid in self.uids]))
            rows["seg"].append(np.stack([sensors[uid]["segmentation"][0, ..., 0].cpu().numpy() for uid in self.uids]))
            rows["cam_intrinsic"].append(np.stack([params[uid]["intrinsic_cv"][0].cpu().numpy() for uid in self.uids]))
            rows["cam_extrinsic"].append(np.stack([params[uid]["extrinsic_cv"][0].cpu().numpy() for uid in self.uids]))
            for k, v in envs.task_readouts(self.env, after_reset=t == 0).items():
                rows[k].append(v)
            # step the physics without rendering an observation we would throw away
            u._step_action(torch.as_tensor(action[None], dtype=torch.float32))
            u._elapsed_steps += 1
            info = u.get_info()
            max_err = max(max_err, float(np.abs(_flat_current(self.env, states) - _flat_state(states, t + 1)).max()))
        arrays = {k: np.asarray(v) for k, v in rows.items()}
        arrays["action"] = actions.astype(np.float32)
        arrays["goal2d_exact"] = projection.goal2d(
            arrays["goal_pos"], arrays["cam_intrinsic"], arrays["cam_extrinsic"], self.resolution
        ).astype(np.float32)
        arrays["goal2d_approx"] = projection.goal2d(
            arrays["goal_pos"], self.approx_K, self.approx_E, self.resolution
        ).astype(np.float32)
        success = bool(info.get("success", torch.tensor([False]))[0].item())
        return EpisodeFrames(int(episode["episode_id"]), int(episode["episode_seed"]), success, max_err, arrays)


def select_episodes(json_path: str | Path, shard: int, n_shards: int) -> list[dict]:
    """Contiguous block ``shard`` of ``n_shards`` over the demo set's episodes in numeric id order."""
    eps = episodes(json_path)
    bounds = np.linspace(0, len(eps), n_shards + 1).round().astype(int)
    return eps[bounds[shard] : bounds[shard + 1]]
