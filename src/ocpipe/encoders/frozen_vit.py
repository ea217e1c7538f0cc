"""Frozen ViT-based encoders: SPOT (ViT-B/16 + Slot Attention, 7 x 256 with masks) and DINO readouts.

Each owns its preprocessing (ImageNet normalization, applied exactly once, at the encoder's input size)."""

from __future__ import annotations

import math
from pathlib import Path

import torch

from . import checkpoints
from .vit import ImageNetPreprocess, grid_pool

DINO_GRID = {"cls": None, "grid4": 4, "dense": None}


def _images(rgb: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W, 3) uint8 -> (B*C, 3, H, W) uint8, cameras folded into the batch."""
    B, C = rgb.shape[:2]
    return rgb.flatten(0, 1).permute(0, 3, 1, 2)


class FrozenSPOT:
    name = "spot"

    def __init__(self, vit, slot_attention, image_size: int, checkpoint: Path):
        self.vit, self.slot_attention = vit.eval(), slot_attention.eval()
        self.preprocess = ImageNetPreprocess(image_size)
        self.checkpoint = Path(checkpoint)
        self.extra_attrs = {"image_size": image_size}

    @classmethod
    def from_config(cls, spot_cfg: dict, trained_checkpoint: str | Path | None = None) -> "FrozenSPOT":
        """The official SPOT checkpoint (encoders.spot.checkpoint), or, when only DINO weights are given, DINO
        plus the slot module the workflow trained on them (``trained_checkpoint``)."""
        if spot_cfg.get("checkpoint"):
            vit, sa = checkpoints.load_spot(spot_cfg["checkpoint"], config_key="encoders.spot.checkpoint")
            return cls(vit, sa, spot_cfg["image_size"], spot_cfg["checkpoint"])
        if spot_cfg.get("dino_checkpoint") and trained_checkpoint:
            vit = checkpoints.load_dino_vit(spot_cfg["dino_checkpoint"], config_key="encoders.spot.dino_checkpoint")
            from .dinosaur import load_slot_module

            return cls(vit, load_slot_module(trained_checkpoint), spot_cfg["image_size"], trained_checkpoint)
        raise FileNotFoundError(
            "encoder 'spot' needs weights: set encoders.spot.checkpoint to SPOT's checkpoint.pt.tar (COCO release, "
            "SPOT GitHub repository) or encoders.spot.dino_checkpoint to dino_vitbase16_pretrain.pth "
            f"({checkpoints.DINO_URL}); neither is downloadable offline")

    def encode(self, rgb: torch.Tensor):
        B, C = rgb.shape[:2]
        x = self.preprocess(_images(rgb))
        # SPOT reads the last block's tokens without the final norm, CLS dropped
        tokens = self.vit.forward_features(x, final_norm=False)[:, 1:]
        slots, attn = self.slot_attention(tokens)
        side = int(math.isqrt(tokens.shape[1]))
        masks = attn.reshape(B, C, attn.shape[1], side, side)
        return slots.reshape(B, C, *slots.shape[1:]), masks


class FrozenDINO:
    def __init__(self, vit, readout: str, image_size: int, checkpoint: Path):
        if readout not in DINO_GRID:
            raise ValueError(f"unknown DINO readout {readout!r}; known: {', '.join(DINO_GRID)}")
        self.vit, self.readout = vit.eval(), readout
        self.name = f"dino_{readout}"
        self.preprocess = ImageNetPreprocess(image_size)
        self.checkpoint = Path(checkpoint)
        self.extra_attrs = {"image_size": image_size, "readout": readout}

    @classmethod
    def from_config(cls, dino_cfg: dict, readout: str) -> "FrozenDINO":
        path = dino_cfg.get("checkpoint")
        if not path:
            raise FileNotFoundError(
                f"encoder 'dino_{readout}' needs weights: set encoders.dino.checkpoint to dino_vitbase16_pretrain.pth "
                f"({checkpoints.DINO_URL}) or timm's vit_base_patch16_224.dino weights; not downloadable offline")
        vit = checkpoints.load_dino_vit(path, config_key="encoders.dino.checkpoint")
        return cls(vit, readout, dino_cfg["image_size"], path)

    def encode(self, rgb: torch.Tensor):
        B, C = rgb.shape[:2]
        feats = self.vit.forward_features(self.preprocess(_images(rgb)), final_norm=True)
        if self.readout == "cls":
            tokens = feats[:, :1]
        elif self.readout == "grid4":
            tokens = grid_pool(feats[:, 1:], 4)
        else:
            tokens = feats[:, 1:]
        return tokens.reshape(B, C, *tokens.shape[1:]), None
