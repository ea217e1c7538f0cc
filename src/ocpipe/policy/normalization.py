"""Normalization statistics, computed once from the training frames and stored in every checkpoint.

Actions: the 7 joint targets are z-scored per dimension; the gripper command (-1/+1) is left untouched.
With `joint_targets: residual` the model predicts each target minus the current joints instead, z-scored per
(horizon step, joint): a joint moves a few hundredths of a radian per step while its absolute angle spans ~1 rad,
so the same normalized error is an order of magnitude finer in radians.
Proprioception, by the `proprio` setting:
  joints7        qpos[:7], z-scored per joint.
  qpos9_global   qpos[:9] with ONE mean/std pooled over all 9 dims: the thesis' pathology, since finger widths
                 (0.018-0.040 m) are tiny next to joint angles (radians) and end up nearly constant after scaling.
  qpos9_grouped  qpos[:9], joints z-scored per joint, the two fingers with one pooled mean/std of their own.
  joints7_tcp    qpos[:7] and the gripper's tool-centre point (xyz, world frame), z-scored per dimension: the
                 robot's own hand position, so the policy need not learn forward kinematics from 100 demos to
                 relate its hand to the object.
Goal: as given (the 3D goal in metres, the 2D one in image fractions), or with `goal_norm: zscore` z-scored per
dimension: the 2D goal of the workspace spans only ~0.1 of the image, so a success radius of 2.5 cm is ~0.02 of
an input the network first has to scale up."""

from __future__ import annotations

import numpy as np

EPS = 1e-6


def _pooled(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.full(x.shape[1], x.mean()), np.full(x.shape[1], x.std())


PROPRIO_MODES = ("joints7", "qpos9_global", "qpos9_grouped", "joints7_tcp")


def proprio_input(qpos: np.ndarray, tcp_pos: np.ndarray | None, mode: str) -> np.ndarray:
    """The raw proprioception vector of a mode, from the robot's qpos (..., 9) and TCP position (..., 3)."""
    if mode == "joints7_tcp":
        if tcp_pos is None:
            raise ValueError("policy.proprio joints7_tcp needs the TCP position (frames store array tcp_pos)")
        return np.concatenate([qpos[..., :7], tcp_pos], axis=-1)
    return qpos[..., : (7 if mode == "joints7" else 9)]


def proprio_stats(x: np.ndarray, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """Mean/std of the proprioception vectors ``x`` (n, P) of ``mode`` (see proprio_input)."""
    if mode in ("joints7", "joints7_tcp"):
        return x.mean(0), x.std(0)
    if mode == "qpos9_global":
        return _pooled(x[:, :9])
    if mode == "qpos9_grouped":
        (jm, js), (fm, fs) = (x[:, :7].mean(0), x[:, :7].std(0)), _pooled(x[:, 7:9])
        return np.concatenate([jm, fm]), np.concatenate([js, fs])
    raise ValueError(f"policy.proprio: unknown mode {mode!r} (allowed: {', '.join(PROPRIO_MODES)})")


def goal(x: np.ndarray, stats: dict) -> np.ndarray:
    """The goal as the policy sees it: z-scored per dimension for a policy trained with `goal_norm: zscore` (its
    stats hold goal_mean / goal_std), else as given."""
    if "goal_mean" not in stats:
        return x
    return ((x - stats["goal_mean"]) / stats["goal_std"]).astype(np.float32)


def compute(proprio_x: np.ndarray, action: np.ndarray, proprio_mode: str) -> dict[str, np.ndarray]:
    """Stats of the training frames: ``proprio_x`` their proprio_input vectors, ``action`` their actions."""
    am, asd = action.mean(0), action.std(0)
    am[7], asd[7] = 0.0, 1.0  # gripper untouched
    pm, psd = proprio_stats(proprio_x.astype(np.float64), proprio_mode)
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    return {"action_mean": f32(am), "action_std": f32(np.maximum(asd, EPS)),
            "proprio_mean": f32(pm), "proprio_std": f32(np.maximum(psd, EPS))}


def residual_stats(action: np.ndarray, qpos: np.ndarray, current: np.ndarray, targets: np.ndarray
                   ) -> dict[str, np.ndarray]:
    """Per-(horizon step, dim) stats of target minus current joints; ``targets`` (n, H) are the target frames of
    the current frames ``current`` (n,). The gripper stays untouched."""
    res = action[targets] - residual_base(qpos[current])[:, None]
    mean, std = res.mean(0), res.std(0)
    mean[:, 7], std[:, 7] = 0.0, 1.0
    return {"action_mean": mean.astype(np.float32), "action_std": np.maximum(std, EPS).astype(np.float32)}


def residual_base(qpos: np.ndarray) -> np.ndarray:
    """What a residual action is relative to: the current arm joints, and 0 for the gripper."""
    base = np.zeros((*qpos.shape[:-1], 8), dtype=np.float32)
    base[..., :7] = qpos[..., :7]
    return base


def proprio(x: np.ndarray, stats: dict) -> np.ndarray:
    """Z-score proprio_input vectors (..., P) with the training statistics."""
    return ((x - stats["proprio_mean"]) / stats["proprio_std"]).astype(np.float32)


def action_to_model(action: np.ndarray, stats: dict) -> np.ndarray:
    return ((action - stats["action_mean"]) / stats["action_std"]).astype(np.float32)


def action_from_model(pred: np.ndarray, stats: dict, gripper_threshold: float = 0.0,
                      qpos: np.ndarray | None = None) -> np.ndarray:
    """De-normalize joints (adding the current joints ``qpos`` back for residual targets); gripper = +1 (open)
    if the output (or BCE logit) > threshold else -1 (closed). ``pred`` is (H, 8) or (B, H, 8)."""
    out = pred * stats["action_std"] + stats["action_mean"]
    if qpos is not None:
        out = out + residual_base(np.asarray(qpos, dtype=np.float32))[..., None, :]
    out[..., 7] = np.where(pred[..., 7] > gripper_threshold, 1.0, -1.0)
    return out.astype(np.float32)
