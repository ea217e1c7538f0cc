"""Per-target loss weights from episode progress p in [0, 1], shape (..., 8): 7 joints + gripper
(docs/study.md, Policy, Ablations).

  uniform        1 everywhere.
  time           1 + p (a linear ramp to 2 at the episode's end); uniform during the first warm-up epochs.
  u_shaped       1 + (2.0 - 1) * [G(p; 0.35, 0.15) + G(p; 0.85, 0.15)], G an unnormalized Gaussian: peaks of
                 height 2.0 at p = 0.35 (grasp) and p = 0.85 (placing), width (sigma) 0.15.
  dim_decoupled  p < 0.4: gripper 3, joints 1; p >= 0.4: gripper 1, joints 3."""

from __future__ import annotations

import torch

U_PEAKS = (0.35, 0.85)
U_HEIGHT = 2.0
U_WIDTH = 0.15
SPLIT = 0.4
EARLY = (1.0, 3.0)  # (joints, gripper) before the split
LATE = (3.0, 1.0)


def loss_weights(kind: str, progress: torch.Tensor, epoch: int = 0, warmup_epochs: int = 0) -> torch.Tensor:
    """progress (...) -> weights (..., 8). ``epoch`` is 0-based."""
    p = progress.float()
    ones = torch.ones(*p.shape, 8, dtype=p.dtype, device=p.device)
    if kind == "uniform" or (kind == "time" and epoch < warmup_epochs):
        return ones
    if kind == "time":
        return ones * (1.0 + p)[..., None]
    if kind == "u_shaped":
        bumps = sum(torch.exp(-0.5 * ((p - c) / U_WIDTH) ** 2) for c in U_PEAKS)
        return ones * (1.0 + (U_HEIGHT - 1.0) * bumps)[..., None]
    if kind == "dim_decoupled":
        early = (p < SPLIT)[..., None]
        joints = torch.where(early, EARLY[0], LATE[0]).expand(*p.shape, 7)
        gripper = torch.where(early, EARLY[1], LATE[1])
        return torch.cat([joints, gripper], dim=-1).to(p.dtype)
    raise ValueError(f"policy.loss_weighting: unknown {kind!r} (allowed: uniform, time, u_shaped, dim_decoupled)")
