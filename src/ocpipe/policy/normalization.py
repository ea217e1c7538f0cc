"""Normalization statistics, computed once from the training frames and stored in every checkpoint.

Actions: the 7 joint targets are z-scored per dimension; the gripper command (-1/+1) is left untouched.
Proprioception, by the `proprio` setting:
  joints7        qpos[:7], z-scored per joint.
  qpos9_global   qpos[:9] with ONE mean/std pooled over all 9 dims: the thesis' pathology, since finger widths
                 (0.018-0.040 m) are tiny next to joint angles (radians) and end up nearly constant after scaling.
  qpos9_grouped  qpos[:9], joints z-scored per joint, the two fingers with one pooled mean/std of their own."""

from __future__ import annotations

import numpy as np

EPS = 1e-6


def _pooled(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.full(x.shape[1], x.mean()), np.full(x.shape[1], x.std())


def proprio_stats(qpos: np.ndarray, mode: str) -> tuple[np.ndarray, np.ndarray]:
    if mode == "joints7":
        x = qpos[:, :7]
        return x.mean(0), x.std(0)
    if mode == "qpos9_global":
        return _pooled(qpos[:, :9])
    if mode == "qpos9_grouped":
        (jm, js), (fm, fs) = (qpos[:, :7].mean(0), qpos[:, :7].std(0)), _pooled(qpos[:, 7:9])
        return np.concatenate([jm, fm]), np.concatenate([js, fs])
    raise ValueError(f"policy.proprio: unknown mode {mode!r} (allowed: joints7, qpos9_global, qpos9_grouped)")


def compute(qpos: np.ndarray, action: np.ndarray, proprio_mode: str) -> dict[str, np.ndarray]:
    am, asd = action.mean(0), action.std(0)
    am[7], asd[7] = 0.0, 1.0  # gripper untouched
    pm, psd = proprio_stats(qpos.astype(np.float64), proprio_mode)
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    return {"action_mean": f32(am), "action_std": f32(np.maximum(asd, EPS)),
            "proprio_mean": f32(pm), "proprio_std": f32(np.maximum(psd, EPS))}


def proprio(qpos: np.ndarray, stats: dict) -> np.ndarray:
    dims = len(stats["proprio_mean"])
    return ((qpos[..., :dims] - stats["proprio_mean"]) / stats["proprio_std"]).astype(np.float32)


def action_to_model(action: np.ndarray, stats: dict) -> np.ndarray:
    return ((action - stats["action_mean"]) / stats["action_std"]).astype(np.float32)


def action_from_model(pred: np.ndarray, stats: dict, gripper_threshold: float = 0.0) -> np.ndarray:
    """De-normalize joints; gripper = +1 (closed) if the output (or BCE logit) > threshold else -1."""
    out = pred * stats["action_std"] + stats["action_mean"]
    out[..., 7] = np.where(pred[..., 7] > gripper_threshold, 1.0, -1.0)
    return out.astype(np.float32)
