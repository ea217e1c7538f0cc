"""Every statistic a policy standardizes with, in one module that is part of the model: fitted once on the
training frames, saved with the checkpoint's weights, applied the same way in training and the closed loop.

Inputs (raw, as policy.observation builds them):
  tokens     per token dimension, pooled over cameras and slots (`token_norm: zscore`; identity otherwise)
  readout    the object read-out's input, per camera x slot x dimension (`readout_standardize: element`)
  proprio    by `proprio`: joints7 / joints7_tcp z-scored per dimension; qpos9_global with ONE mean/std pooled
             over all 9 dims (the study's pathology: finger widths, 0.018-0.040 m, end up nearly constant next to
             joint angles in radians); qpos9_grouped per joint, the two fingers with one pooled mean/std
  goal       per dimension (`goal_norm: zscore`): the 2D goal spans ~0.1 of the image; identity otherwise
Targets:
  action     the 7 joint targets per dimension, the gripper command (-1/+1) untouched; with `joint_targets:
             residual` each target minus the current joints, per (horizon step, joint): a joint moves a few
             hundredths of a radian per step while its angle spans ~1 rad, so the same normalized error is an
             order of magnitude finer
  pose       the object read-out's targets (xyz, sin/cos 4x yaw)
  aux        the auxiliary head's target (the object's xyz)"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

EPS = 1e-6  # the floor of every std: a constant dimension passes through unscaled


def fit(x: np.ndarray, pooled: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Mean/std over the first axis of ``x`` (computed in its dtype), the std floored at EPS; ``pooled``: one
    mean/std over every element, repeated per dimension."""
    mean, std = (np.full(x.shape[1:], x.mean()), np.full(x.shape[1:], x.std())) if pooled else (x.mean(0), x.std(0))
    return np.asarray(mean, dtype=np.float32), np.maximum(std, EPS).astype(np.float32)


class Standardize(nn.Module):
    """(x - mean) / std over the last dims ``shape``; identity until fitted (mean 0, std 1)."""

    def __init__(self, shape: tuple[int, ...]):
        super().__init__()
        self.register_buffer("mean", torch.zeros(shape))
        self.register_buffer("std", torch.ones(shape))

    def set(self, mean, std) -> None:
        self.mean.copy_(torch.as_tensor(np.asarray(mean), dtype=torch.float32).reshape(self.mean.shape))
        self.std.copy_(torch.as_tensor(np.asarray(std), dtype=torch.float32).reshape(self.std.shape))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std

    def invert(self, z: torch.Tensor) -> torch.Tensor:
        return z * self.std + self.mean


def residual_base(qpos: torch.Tensor) -> torch.Tensor:
    """What a residual action is relative to: the current arm joints (..., 7 of qpos), and 0 for the gripper."""
    return nn.functional.pad(qpos[..., :7], (0, 1))


class Normalizer(nn.Module):
    """The standardizations of one policy (module docstring); ``dims``: K, D, C (cameras), P (proprio), G (goal)."""

    def __init__(self, policy, K: int, D: int, C: int, P: int, G: int):
        super().__init__()
        self.tokens = Standardize((D,))
        self.readout = Standardize((C * K * D,)) if policy.readout.enabled else None
        self.readout_elementwise = policy.readout.enabled and policy.readout.standardize == "element"
        self.proprio = Standardize((P,))
        self.goal = Standardize((G,))
        self.residual = policy.training.joint_targets == "residual"
        self.action = Standardize((policy.network.horizon, 8) if self.residual else (8,))
        self.pose = Standardize((5,)) if policy.readout.enabled else None
        self.aux = Standardize((3,)) if policy.training.aux_object_weight > 0 else None

    def readout_input(self, tokens: torch.Tensor) -> torch.Tensor:
        """Raw tokens (..., C, K, D) -> the object read-out's standardized input (..., C * K * D)."""
        if self.readout_elementwise:
            return self.readout(tokens.flatten(-3))
        return self.tokens(tokens).flatten(-3)

    def actions_to_model(self, action: torch.Tensor, qpos: torch.Tensor) -> torch.Tensor:
        """Raw target actions (B, H, 8) of current joints ``qpos`` (B, >= 7) -> what the model predicts."""
        if self.residual:
            action = action - residual_base(qpos)[:, None]
        z = self.action(action)
        return torch.cat([z[..., :7], action[..., 7:]], -1)  # the gripper command stays -1/+1

    def actions_from_model(self, pred: torch.Tensor, qpos: torch.Tensor, threshold: float = 0.0) -> torch.Tensor:
        """Model output (B, H, 8) -> executable actions: joints de-normalized (plus the current joints for residual
        targets), gripper +1 (open) where the output (or BCE logit) > threshold, else -1 (closed)."""
        out = self.action.invert(pred)
        if self.residual:
            out = out + residual_base(qpos)[:, None]
        return torch.cat([out[..., :7], torch.where(pred[..., 7:] > threshold, 1.0, -1.0)], -1)

    @torch.no_grad()
    def fit(self, policy, proprio: np.ndarray, goal: np.ndarray, action: np.ndarray, qpos_at: np.ndarray | None,
            pose: np.ndarray | None, aux: np.ndarray | None) -> None:
        """Fit on the training frames' raw inputs and targets: ``action`` (n, 8) absolute targets or (n, H, 8)
        targets of current frames whose joints are ``qpos_at`` (n, 9) for residual targets. The token and
        read-out input statistics come from fit_tokens and fit_readout."""
        mode = policy.network.proprio
        x = proprio.astype(np.float64)
        if mode == "qpos9_global":
            self.proprio.set(*fit(x[:, :9], pooled=True))
        elif mode == "qpos9_grouped":
            (jm, js), (fm, fs) = fit(x[:, :7]), fit(x[:, 7:9], pooled=True)
            self.proprio.set(np.concatenate([jm, fm]), np.concatenate([js, fs]))
        else:
            self.proprio.set(*fit(x))
        if policy.goal.norm == "zscore" and goal.shape[1]:
            self.goal.set(*fit(goal))
        if self.residual:
            action = action - np.pad(qpos_at[:, :7], ((0, 0), (0, 1)))[:, None]
        mean, std = fit(action)
        mean[..., 7], std[..., 7] = 0.0, 1.0
        self.action.set(mean, std)
        if self.pose is not None:
            self.pose.set(*fit(pose))
        if self.aux is not None:
            self.aux.set(*fit(aux))
