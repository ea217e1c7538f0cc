"""Workspace crops: the part of each fixed camera's image where the task happens.

At 128 px the base camera sees the whole 0.2 m cube workspace in about 20 pixels and the cube in about 4, so a
slot encoder that looks at the full frame spends nearly all its capacity on wall and table. Cropping to the
projected workspace box (then resizing to the encoder grid) multiplies the cube's share of the input ~10x."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from ..sim.projection import project_points


def workspace_corners(box_min, box_max) -> np.ndarray:
    lo, hi = np.asarray(box_min, float), np.asarray(box_max, float)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def crop_windows(intrinsics: np.ndarray, extrinsics: np.ndarray, resolution: int, box_min, box_max,
                 pad_px: float = 2.0) -> np.ndarray:
    """Square crop window (x0, y0, size) in pixels per camera, covering the projected workspace box.

    A camera whose matrices are NaN or that sees the box behind itself gets the full image."""
    corners = workspace_corners(box_min, box_max)
    windows = []
    for K, E in zip(intrinsics, extrinsics):
        cam_z = (E[:, :3] @ corners.T + E[:, 3:4])[2]
        if not np.isfinite(K).all() or not np.isfinite(E).all() or (cam_z <= 0).any():
            windows.append((0, 0, resolution))
            continue
        uv = project_points(corners, K, E)
        lo, hi = uv.min(0) - pad_px, uv.max(0) + pad_px
        size = int(np.ceil(min(resolution, max(hi - lo))))
        centre = (lo + hi) / 2
        x0, y0 = (np.clip(np.round(centre - size / 2), 0, resolution - size)).astype(int)
        windows.append((int(x0), int(y0), size))
    return np.array(windows, dtype=np.int64)


def crop_and_resize(rgb: torch.Tensor, windows: np.ndarray, grid: int) -> torch.Tensor:
    """rgb (B, C, H, W, 3) uint8 -> (B, C, 3, grid, grid) float in [0, 1], each camera cropped to its window."""
    out = []
    for c, (x0, y0, size) in enumerate(windows):
        img = rgb[:, c, y0 : y0 + size, x0 : x0 + size].permute(0, 3, 1, 2).float() / 255.0
        out.append(F.interpolate(img, size=(grid, grid), mode="area") if size != grid else img)
    return torch.stack(out, dim=1)


def crop_labels(seg: np.ndarray, windows: np.ndarray, grid: int) -> np.ndarray:
    """Per-pixel ids (B, C, H, W) -> (B, C, grid, grid) by nearest sampling at the grid cells' centres."""
    out = []
    for c, (x0, y0, size) in enumerate(windows):
        idx = (
            (x0 + (np.arange(grid) + 0.5) * size / grid).astype(int),
            (y0 + (np.arange(grid) + 0.5) * size / grid).astype(int),
        )
        out.append(seg[:, c][:, idx[1]][:, :, idx[0]])
    return np.stack(out, axis=1)
