"""Labelled extra scenes for the object read-out: frozen tokens of scenes no demo shows, with the object's pose.

A features store of N demos shows the object at N places only, and a read-out of its position fitted on those
frames learns those places rather than where the object is (docs/journal.md, "Is the cube in the tokens?").
These scenes are resets of seeds outside the demo and evaluation pools, each with the arm put in a pre-grasp pose
of a random demo frame (the frames store's `qpos` where nothing is grasped), rendered by the study's cameras and
encoded by the same frozen encoder as the features store. A share ``near_fraction`` of them also moves the object
to within ``near_radius`` of where it lay in that demo frame, at a random yaw, so the hand is beside or above it
as in a closed-loop approach that is off by a few centimetres. Nothing is simulated: the scene is drawn where the
reset, the arm pose and the placement put it. The store holds `tokens` (N, C, K, D) in the features store's
dtype, and `obj_pos`, `obj_quat` and `tcp_pos` per scene.

Jobs render consecutive shards of a store and `merge_scenes` joins them into the store one job would write:
every scene's arm pose and placement is drawn up front, from one stream for the whole store."""

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
SHARD_ATTRS = ("shard", "shards", "first")  # a shard store's place in its store (absent from a whole store)


def scene_plan(count: int, seed: int, n_poses: int, near_fraction: float) -> list[tuple[int, tuple | None]]:
    """Per scene, in order: the index of the demo arm pose it takes and, for a near scene, the three uniforms of
    its placement (radius, angle, half-yaw). One stream for the whole store, so that a shard renders its scenes
    exactly as an unsharded job would."""
    rng = np.random.default_rng(seed)
    plan = []
    for _ in range(count):
        j = int(rng.integers(n_poses))
        near = bool(near_fraction) and rng.random() < near_fraction  # (no draw at 0: the arm poses stay as before)
        plan.append((j, (rng.random(), rng.random(), rng.random()) if near else None))
    return plan


def shard_range(count: int, shard: int, shards: int) -> range:
    """The scenes of shard ``shard`` of ``shards``: consecutive, the shards together covering 0..count-1."""
    if not 0 <= shard < shards:
        raise ValueError(f"scenes shard {shard} of {shards}: the shard must be in 0..{shards - 1}")
    return range(count * shard // shards, count * (shard + 1) // shards)


def render_scenes(encoder, config: dict, task: str, camera_set: str, resolution: int, frames_path: str | Path,
                  out_path: str | Path, count: int, seed_start: int, seed: int, dtype: str = "float16",
                  near_fraction: float = 0.0, near_radius: float = 0.05, progress: bool = True, shard: int = 0,
                  shards: int = 1) -> dict:
    """Render and encode ``count`` scenes (reset seeds ``seed_start`` ...) into the store at ``out_path``; with
    ``shards`` > 1, only this shard's scenes (``shard_range``), for `merge_scenes` to join."""
    problems = scene_seed_problems({**config, "scenes": {"seed_start": seed_start, "count": count}})
    if problems:
        raise ValueError("\n".join(p.strip() for p in problems))
    frames = open_store(frames_path, need=("qpos", "is_grasped", "obj_pos"))
    free = ~frames["is_grasped"][...].astype(bool)
    arm_poses, arm_objects = frames["qpos"][...][free], frames["obj_pos"][...][free]
    if not len(arm_poses):
        raise ValueError(f"{frames_path}: no frame without a grasp to take an arm pose from")
    plan = scene_plan(count, seed, len(arm_poses), near_fraction)
    mine = shard_range(count, shard, shards)
    env = envs.make_env(task, config, camera_set, resolution)
    uids = [envs.SIM_CAMERA_UID[c] for c in envs.CAMERA_SETS[camera_set]]
    tokens, labels = [], {k: [] for k in LABELS}
    desc = f"scenes {task}" + (f" shard {shard}/{shards}" if shards > 1 else "")
    try:
        for i in tqdm(mine, desc=desc, unit="scene", disable=not progress):
            j, near = plan[i]
            env.reset(seed=seed_start + i)
            env.unwrapped.agent.robot.set_qpos(torch.as_tensor(arm_poses[j][None], dtype=torch.float32))
            if near is not None:
                place_near(env, arm_objects[j], near_radius, near)
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
    attrs = {"encoder": encoder.name, "checkpoint_sha256": sha256(encoder.checkpoint),
             "frames_store": str(frames_path), "seed_start": seed_start, "count": count,
             "near_fraction": near_fraction, "near_radius": near_radius,
             "task": task, "camera_set": camera_set, "resolution": resolution}
    if shards > 1:
        attrs.update(dict(zip(SHARD_ATTRS, (shard, shards, mine.start), strict=True)))
    _write(out_path, np.stack(tokens).astype(dtype), {k: np.stack(v) for k, v in labels.items()}, attrs)
    return {"scenes": len(mine)}


def merge_scenes(shard_paths: list[str | Path], out_path: str | Path) -> dict:
    """Join the shards of one scenes store, in scene order, into the store an unsharded job would have written.
    Refused when the shards are not all the shards of one store."""
    shards = sorted(((p, zarr.open_group(str(p), mode="r")) for p in shard_paths),
                    key=lambda pr: pr[1].attrs.get("shard", 0))
    roots = [root for _, root in shards]
    whole = {k: v for k, v in roots[0].attrs.items() if k not in SHARD_ATTRS}
    n = roots[0].attrs.get("shards", 1)
    got = [r.attrs.get("shard", 0) for r in roots]
    if got != list(range(n)):
        missing = sorted(set(range(n)) - set(got))
        raise ValueError(f"{out_path}: a scenes store of {n} shards, but shards {got} were given"
                         + (f" (missing: {missing})" if missing else ""))
    for s, (path, root) in enumerate(shards):
        a = dict(root.attrs)
        same_store = {k: v for k, v in a.items() if k not in SHARD_ATTRS} == whole
        if not same_store or a.get("shards", 1) != n or a.get("first", 0) != shard_range(whole["count"], s, n).start:
            raise ValueError(f"{path}: not shard {s} of the {n} shards of one scenes store (another count, seeds, "
                             "encoder or frames store): delete the shards and rerun")
    tok = np.concatenate([r["tokens"][...] for r in roots])
    if len(tok) != whole["count"]:
        raise ValueError(f"{out_path}: the shards hold {len(tok)} scenes, not the store's {whole['count']}")
    _write(out_path, tok, {k: np.concatenate([r[k][...] for r in roots]) for k in LABELS}, whole)
    return {"scenes": len(tok), "shards": n}


def _write(out_path, tok: np.ndarray, labels: dict[str, np.ndarray], attrs: dict) -> None:
    with atomic_path(out_path) as tmp:
        root = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        root.create_array("tokens", shape=tok.shape, dtype=tok.dtype, chunks=(min(len(tok), 4096), *tok.shape[1:]))
        root["tokens"][...] = tok
        for k, v in labels.items():
            arr = v.astype(np.float32)
            root.create_array(k, shape=arr.shape, dtype="float32")
            root[k][...] = arr
        root.attrs.update(attrs)


def place_near(env, where: np.ndarray, radius: float, uniforms: tuple[float, float, float]) -> None:
    """Put the task's object at a uniform random point of the disc of ``radius`` around ``where`` (same height),
    turned to a uniform random yaw; ``uniforms``: three draws in [0, 1) (radius, angle, half-yaw)."""
    u_r, u_a, u_yaw = uniforms
    r, a = radius * np.sqrt(u_r), 2 * np.pi * u_a
    pos = np.asarray(where, np.float64) + [r * np.cos(a), r * np.sin(a), 0.0]
    half = np.pi * u_yaw  # half the yaw: a quaternion about z is (cos, 0, 0, sin) of it
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
