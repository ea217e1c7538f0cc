"""The trained `slots_ssl` encoder, frozen, as the features stage uses it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from . import crop, ssl_slots


class FrozenSSLSlots:
    name = "slots_ssl"

    def __init__(self, checkpoint: str | Path, intrinsics: np.ndarray, extrinsics: np.ndarray, resolution: int):
        self.checkpoint = Path(checkpoint)
        self.model, ckpt = ssl_slots.load(self.checkpoint)
        for p in self.model.parameters():
            p.requires_grad_(False)
        # windows come from this store's own camera matrices, so a camera set the encoder never saw still crops
        # the same world box
        self.windows = crop.crop_windows(
            intrinsics, extrinsics, resolution, ckpt["workspace_min"], ckpt["workspace_max"]
        )
        self.extra_attrs = {"crop_windows": self.windows.tolist(), "mask_grid": self.model.cfg.grid}

    def encode(self, rgb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """rgb (B, C, H, W, 3) uint8 -> slots (B, C, K, D), masks (B, C, K, g, g)."""
        x = crop.crop_and_resize(rgb, self.windows, self.model.cfg.grid)  # (B, C, 3, g, g), in [0, 1]
        # same quantization as training, which saw uint8 crops
        x = (x * 255).round() / 255
        B, C = x.shape[:2]
        slots, masks = self.model.encode(x.flatten(0, 1))
        return slots.reshape(B, C, *slots.shape[1:]), masks.reshape(B, C, *masks.shape[1:])
