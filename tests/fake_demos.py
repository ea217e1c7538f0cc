"""ManiSkill-format demo files with made-up contents, written in the layout the official files use."""

import json

import h5py
import numpy as np


def write(path_h5, seeds, lengths=None, control_mode="pd_joint_pos", env_id="PickCube-v1", json_order=None):
    """Episode i has id i, seed seeds[i]; actions[t, 0] == i and actions[t, 1] == t so tests can trace rows."""
    lengths = lengths or [5 + i % 3 for i in range(len(seeds))]
    eps = []
    with h5py.File(path_h5, "w") as f:
        for i, (seed, T) in enumerate(zip(seeds, lengths)):
            g = f.create_group(f"traj_{i}")
            actions = np.zeros((T, 8), np.float32)
            actions[:, 0], actions[:, 1], actions[:, 7] = i, np.arange(T), -1
            g["actions"] = actions
            qpos = np.tile(np.arange(9, dtype=np.float32), (T + 1, 1)) + np.arange(T + 1)[:, None]
            g["env_states/articulations/panda"] = np.concatenate(
                [np.zeros((T + 1, 13), np.float32), qpos, np.zeros((T + 1, 9), np.float32)], axis=1)
            g["env_states/actors/cube"] = np.zeros((T + 1, 13), np.float32)
            eps.append({"episode_id": i, "episode_seed": seed, "control_mode": control_mode, "elapsed_steps": T,
                        "reset_kwargs": {"seed": seed, "options": None}, "success": True})
    order = json_order or range(len(eps))
    meta = {"env_info": {"env_id": env_id, "env_kwargs": {"control_mode": control_mode}},
            "episodes": [eps[i] for i in order]}
    path_json = str(path_h5)[: -len(".h5")] + ".json"
    with open(path_json, "w") as fh:
        json.dump(meta, fh)
    return path_json
