"""What a policy reads at a step, built one way from either source: a frames store (training, every frame at
once) or one simulator step (the closed loop, a batch of one). Training and the closed loop call the same
functions, so what a policy was trained on and what it acts on cannot drift apart. Everything here is raw:
the policy's Normalizer standardizes it.

    labels   dict of per-step arrays, each (N, ...): qpos (N, 9), tcp_pos, goal_pos, obj_pos (N, 3),
             obj_quat (N, 4): a frames store's arrays, or ``step_labels`` of one simulator step
    cameras  (intrinsics, extrinsics) the 2D goal is projected with: (C, 3, 3) and (C, 3, 4), or per frame
             (N, C, 3, 3) and (N, C, 3, 4) for a moving camera"""

from __future__ import annotations

import numpy as np
import torch

from ..encoders.state import state_tokens
from ..sim import envs, projection
from .settings import PolicySettings

# what each input reads of the labels (the frames store must hold these arrays)
GOAL_LABELS = ("goal_pos", "tcp_pos")
PROPRIO_MODES = ("joints7", "qpos9_global", "qpos9_grouped", "joints7_tcp")


def labels_needed(policy: PolicySettings) -> tuple[str, ...]:
    """The per-step labels a policy's inputs and training targets read."""
    need = ["qpos", "action"]
    if policy.goal.kind != "none":
        need += GOAL_LABELS
    if policy.network.proprio == "joints7_tcp":
        need.append("tcp_pos")
    if policy.training.aux_object_weight > 0 or policy.readout.enabled:
        need.append("obj_pos")
    if policy.readout.enabled:
        need.append("obj_quat")
    return tuple(dict.fromkeys(need))


def proprio(policy: PolicySettings, labels: dict) -> np.ndarray:
    """The proprioception vector (N, P) of the config key `proprio`: the arm's 7 joints, all 9 qpos (with fingers),
    or the 7 joints and the TCP's position."""
    qpos = np.asarray(labels["qpos"], dtype=np.float32)
    if policy.network.proprio == "joints7_tcp":
        return np.concatenate([qpos[..., :7], np.asarray(labels["tcp_pos"], dtype=np.float32)], axis=-1)
    return qpos[..., : (7 if policy.network.proprio == "joints7" else 9)]


def goal(policy: PolicySettings, labels: dict, cameras: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """The goal input (N, G): nothing (G = 0), the goal's xyz (3d), or its projection into each camera (2d,
    image fractions); with `goal_relative: tcp` also the goal minus the TCP, the TCP projected the same way."""
    if policy.goal.kind == "none":
        return np.zeros((len(labels["qpos"]), 0), dtype=np.float32)
    goal = np.asarray(labels["goal_pos"], dtype=np.float32)
    hand = np.asarray(labels["tcp_pos"], dtype=np.float32) if policy.goal.relative == "tcp" else None
    if policy.goal.kind == "2d":
        if cameras is None:
            raise ValueError(f"policy {policy.name!r}: a 2d goal needs the cameras it is projected with")
        goal = projection.goal2d(goal, *cameras, policy.stores.resolution).astype(np.float32)
        if not np.isfinite(goal).all():
            raise ValueError(f"policy {policy.name!r}: the camera set {policy.stores.cams!r} has no "
                             f"{policy.goal.calibration} 2d goal (policy.goal_calibration)")
        if hand is not None:  # kept in float64 until the difference, as every trained 2d policy saw it
            hand = projection.goal2d(hand, *cameras, policy.stores.resolution)
    if hand is None:
        return goal
    return np.concatenate([goal, goal - hand], axis=-1).astype(np.float32)


def store_cameras(policy: PolicySettings, frames, camera_approx: dict | None) -> tuple | None:
    """The cameras a frames store's 2d goal is projected with: the hand-entered model (approx, config
    `camera_approx`) or the store's own camera matrices (exact; per frame for a moving camera)."""
    if policy.goal.kind != "2d":
        return None
    if policy.goal.calibration == "approx":
        return approx_cameras(policy, camera_approx, list(frames.attrs["cameras"]))
    suffix = "_per_frame" if "cam_intrinsic_per_frame" in frames else ""
    names = ("cam_intrinsic" + suffix, "cam_extrinsic" + suffix)
    missing = [n for n in names if n not in frames]
    if missing:
        raise ValueError(f"{frames.store}: frames store has no {missing}, which policy {policy.name!r} needs for "
                         "its exact 2d goal; rerun the workflow to rebuild the store")
    return tuple(frames[n][:] for n in names)


def approx_cameras(policy: PolicySettings, camera_approx: dict | None, names: list[str]) -> tuple:
    if camera_approx is None:
        raise ValueError(f"policy {policy.name!r}: the approx 2d goal needs config camera_approx")
    return envs.approx_camera_matrices({"camera_approx": camera_approx}, names, policy.stores.resolution)


def step_cameras(policy: PolicySettings, obs, uids: list[str], approx: tuple | None) -> tuple | None:
    """The cameras one simulator step's 2d goal is projected with (approx: the model given)."""
    if policy.goal.kind != "2d":
        return None
    if policy.goal.calibration == "approx":
        return approx
    params = obs["sensor_param"]
    K = np.stack([params[u]["intrinsic_cv"][0].cpu().numpy() for u in uids])
    E = np.stack([params[u]["extrinsic_cv"][0].cpu().numpy() for u in uids])
    return K, E


def step_labels(env, first: bool, info: dict | None = None) -> dict:
    """One simulator step's labels, each with a leading axis of 1 (as a frames store's rows); ``info``: what the
    step that led here returned (envs.task_readouts)."""
    labels = envs.task_readouts(env, after_reset=first, info=info)
    return {k: np.asarray(v)[None] for k, v in labels.items()}


def object_pose(labels: dict) -> np.ndarray:
    """The object's pose (N, 5) as the read-out predicts it and the control's token holds it: xyz, sin/cos 4x yaw."""
    return state_tokens(np.asarray(labels["obj_pos"]), np.asarray(labels["obj_quat"]))[:, 0, 0]


def as_stored(tokens: torch.Tensor, dtype: str) -> torch.Tensor:
    """Freshly encoded tokens rounded as the features store holds them (float16 by default), so the closed loop
    reads exactly what training read."""
    return tokens.to(getattr(torch, dtype)).float()
