"""Explicit slot geometry: where each slot's attention mask lies in the image, as numbers a policy can read.

A slot vector carries its object's position only implicitly (the probes decode the cube to about 1-2 cm), and a
small policy trained on 100 demos has to learn that read-out itself. The mask already says it directly: per
slot and camera, the mask's centroid (u, v) in normalized full-image coordinates, its area (share of the mask
grid the slot takes) and its spread (standard deviation along u and v). Two cameras' centroids of the same
object pin down its 3D position. Computed the same way from stored masks (training) and live masks (evaluation).
"""

from __future__ import annotations

import numpy as np
import torch

GEOMETRY_DIMS = 5  # u, v, area, spread_u, spread_v


def full_image_windows(cameras: int, resolution: int) -> np.ndarray:
    """Windows (x0, y0, size) for masks that cover the whole image (encoders without a workspace crop)."""
    return np.tile(np.array([[0, 0, resolution]], dtype=np.int64), (cameras, 1))


def slot_geometry(masks: torch.Tensor, windows: np.ndarray, resolution: int) -> torch.Tensor:
    """masks (..., C, K, h, w), non-negative; windows (C, 3) pixel windows the masks cover -> (..., C, K, 5)."""
    h, w = masks.shape[-2:]
    masks = masks.float()
    win = torch.as_tensor(np.asarray(windows), dtype=torch.float32, device=masks.device)  # (C, 3)
    x0, y0, size = (win[:, i, None, None] for i in range(3))  # (C, 1, 1), broadcast over slots
    # cell centres in normalized full-image coordinates, per camera
    u = (x0 + (torch.arange(w, device=masks.device) + 0.5) / w * size) / resolution  # (C, 1, w)
    v = (y0 + (torch.arange(h, device=masks.device) + 0.5) / h * size) / resolution  # (C, 1, h)
    mass = masks.sum((-2, -1))
    safe = mass.clamp_min(1e-6)
    mu_u = (masks.sum(-2) * u).sum(-1) / safe
    mu_v = (masks.sum(-1) * v).sum(-1) / safe
    var_u = (masks.sum(-2) * (u - mu_u[..., None]) ** 2).sum(-1) / safe
    var_v = (masks.sum(-1) * (v - mu_v[..., None]) ** 2).sum(-1) / safe
    area = mass / (h * w)
    return torch.stack([mu_u, mu_v, area, var_u.clamp_min(0).sqrt(), var_v.clamp_min(0).sqrt()], dim=-1)
