"""Labelled extra scenes for the object read-out: frozen tokens of scenes no demo shows, with the object's pose.

A features store of N demos shows the object at N places only, and a read-out of its position fitted on those
frames learns those places rather than where the object is (docs/journal.md, "Is the cube in the tokens?").
These scenes are resets of seeds outside the demo and evaluation pools, each with the arm put in a pre-grasp pose
of a random demo frame (the frames store's `qpos` where nothing is grasped), rendered by the study's cameras and
encoded by the same frozen encoder as the features store. A share ``near_fraction`` of them also moves the object
to within ``near_radius`` of where it lay in that demo frame, at a random yaw, so the hand is beside or above it
as in a closed-loop approach that is off by a few centimetres. Nothing is simulated: the scene is drawn where the
reset, the arm pose and the placement put it. The store holds `tokens` (N, C, K, D) in the features store's
dtype, and `obj_pos`, `obj_quat` and `tcp_pos` per scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import zarr
from mani_skill.utils.structs.pose import Pose
from tqdm import tqdm

from ..config.validate import scene_seed_problems
from ..frames.store import open_store
from ..sim import envs
from ..util.atomic import atomic_path
from .encode import sha256

LABELS = ("obj_pos", "obj_quat", "tcp_pos")


def render_scenes(encoder, config: dict, task: str, camera_set: str, resolution: int, frames_path: str | Path,
                  out_path: str | Path, count: int, seed_start: int, seed: int, dtype: str = "float16",
                  near_fraction: float = 0.0, near_radius: float = 0.05, progress: bool = True) -> dict:
    """Render and encode ``count`` scenes (reset seeds ``seed_start`` ...) into the store at ``out_path``."""
    problems = scene_seed_problems({**config, "scenes": {"seed_start": seed_start, "count": count}})
    if problems:
        raise ValueError("\n".join(p.strip() for p in problems))
    frames = open_store(frames_path, need=("qpos", "is_grasped", "obj_pos"))
    free = ~frames["is_grasped"][...].astype(bool)
    arm_poses, arm_objects = frames["qpos"][...][free], frames["obj_pos"][...][free]
    if not len(arm_poses):
        raise ValueError(f"{frames_path}: no frame without a grasp to take an arm pose from")
    rng = np.random.default_rng(seed)
    env = envs.make_env(task, config, camera_set, resolution)
    uids = [envs.SIM_CAMERA_UID[c] for c in envs.CAMERA_SETS[camera_set]]
    tokens, labels = [], {k: [] for k in LABELS}
    try:
        for i in tqdm(range(count), desc=f"scenes {task}", unit="scene", disable=not progress):
            env.reset(seed=seed_start + i)
            j = rng.integers(len(arm_poses))
            env.unwrapped.agent.robot.set_qpos(torch.as_tensor(arm_poses[j][None], dtype=torch.float32))
            if near_fraction and rng.random() < near_fraction:  # (no draw at 0: the arm poses stay as before)
                place_near(env, arm_objects[j], near_radius, rng)
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
                           "near_fraction": near_fraction, "near_radius": near_radius,
                           "task": task, "camera_set": camera_set, "resolution": resolution})
    return {"scenes": count}


def place_near(env, where: np.ndarray, radius: float, rng: np.random.Generator) -> None:
    """Put the task's object at a uniform random point of the disc of ``radius`` around ``where`` (same height),
    turned to a uniform random yaw."""
    r, a = radius * np.sqrt(rng.random()), 2 * np.pi * rng.random()
    pos = np.asarray(where, np.float64) + [r * np.cos(a), r * np.sin(a), 0.0]
    half = np.pi * rng.random()  # half the yaw: a quaternion about z is (cos, 0, 0, sin) of it
    quat = np.array([np.cos(half), 0.0, 0.0, np.sin(half)])
    envs.task_object(env).set_pose(Pose.create_from_pq(torch.as_tensor(pos[None], dtype=torch.float32),
                                                       torch.as_tensor(quat[None], dtype=torch.float32)))


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
