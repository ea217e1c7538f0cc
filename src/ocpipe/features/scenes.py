"""Labelled extra scenes for the object read-out: frozen tokens of scenes no demo shows, with the object's pose.

A features store of N demos shows the object at N places only, and a read-out of its position fitted on those
frames learns those places rather than where the object is (docs/measurements.md, "Is the cube in the tokens?").
These scenes are resets of seeds outside the demo and evaluation pools, each with the arm put in a pre-grasp pose
of a random demo frame (the frames store's `qpos` where nothing is grasped), rendered by the study's cameras and
encoded by the same frozen encoder as the features store. Nothing is simulated: the scene is drawn where the
reset and the arm pose put it. The store holds `tokens` (N, C, K, D) in the features store's dtype, and `obj_pos`,
`obj_quat` and `tcp_pos` per scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import zarr
from tqdm import tqdm

from ..config.validate import scene_seed_problems
from ..frames.store import open_store
from ..sim import envs
from ..util.atomic import atomic_path
from .encode import sha256

LABELS = ("obj_pos", "obj_quat", "tcp_pos")


def render_scenes(encoder, config: dict, task: str, camera_set: str, resolution: int, frames_path: str | Path,
                  out_path: str | Path, count: int, seed_start: int, seed: int, dtype: str = "float16",
                  progress: bool = True) -> dict:
    """Render and encode ``count`` scenes (reset seeds ``seed_start`` ...) into the store at ``out_path``."""
    problems = scene_seed_problems({**config, "scenes": {"seed_start": seed_start, "count": count}})
    if problems:
        raise ValueError("\n".join(p.strip() for p in problems))
    frames = open_store(frames_path, need=("qpos", "is_grasped"))
    arm_poses = frames["qpos"][...][~frames["is_grasped"][...].astype(bool)]
    if not len(arm_poses):
        raise ValueError(f"{frames_path}: no frame without a grasp to take an arm pose from")
    rng = np.random.default_rng(seed)
    env = envs.make_env(task, config, camera_set, resolution)
    uids = [envs.SIM_CAMERA_UID[c] for c in envs.CAMERA_SETS[camera_set]]
    tokens, labels = [], {k: [] for k in LABELS}
    try:
        for i in tqdm(range(count), desc=f"scenes {task}", unit="scene", disable=not progress):
            env.reset(seed=seed_start + i)
            qpos = arm_poses[rng.integers(len(arm_poses))]
            env.unwrapped.agent.robot.set_qpos(torch.as_tensor(qpos[None], dtype=torch.float32))
            obs = env.unwrapped.get_obs()  # renders the cameras with the arm where it was just put
            rgb = torch.stack([obs["sensor_data"][u]["rgb"][0] for u in uids])[None]
            with torch.inference_mode():
                tok, _ = encoder.encode(rgb)
            tokens.append(tok[0].cpu().numpy())
            readouts = envs.task_readouts(env)
            for k in LABELS:
                labels[k].append(readouts[k])
    finally:
        env.close()
    tok = np.stack(tokens).astype(dtype)
    with atomic_path(out_path) as tmp:
        root = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        root.create_array("tokens", shape=tok.shape, dtype=tok.dtype, chunks=(min(count, 4096), *tok.shape[1:]))
        root["tokens"][...] = tok
        for k, v in labels.items():
            arr = np.stack(v).astype(np.float32)
            root.create_array(k, shape=arr.shape, dtype="float32")
            root[k][...] = arr
        root.attrs.update({"encoder": encoder.name, "checkpoint_sha256": sha256(encoder.checkpoint),
                           "frames_store": str(frames_path), "seed_start": seed_start, "count": count,
                           "task": task, "camera_set": camera_set, "resolution": resolution})
    return {"scenes": count}


def open_scenes(path: str | Path, encoder_sha256: str | None) -> zarr.Group:
    """A scenes store, refused when it was encoded by other encoder weights than the features the policy reads."""
    root = zarr.open_group(str(path), mode="r")
    missing = [k for k in ("tokens", *LABELS) if k not in root]
    if missing:
        raise ValueError(f"{path}: not a scenes store (no {', '.join(missing)}): delete it and rerun the workflow")
    if root.attrs.get("checkpoint_sha256") != encoder_sha256:
        raise ValueError(f"{path} was encoded by other encoder weights than the features store: delete it and rerun "
                         "the workflow")
    return root
