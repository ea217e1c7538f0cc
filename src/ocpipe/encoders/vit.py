"""ViT-B/16 written here, with the exact parameter names of the official DINO release
(`dino_vitbase16_pretrain.pth`, also timm's `vit_base_patch16_224.dino`), so those files load with a strict
key match. Position embeddings are interpolated for inputs other than 224 px (e.g. 128 px -> 8 x 8 patches)."""

from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class PatchEmbed(nn.Module):
    def __init__(self, patch: int, dim: int):
        super().__init__()
        self.proj = nn.Conv2d(3, dim, patch, stride=patch)

    def forward(self, x):
        return self.proj(x).flatten(2).transpose(1, 2)


class Attention(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, dim * 3, bias=True)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x):
        B, N, D = x.shape
        q, k, v = self.qkv(x).reshape(B, N, 3, self.heads, D // self.heads).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q, k, v)
        return self.proj(out.transpose(1, 2).reshape(B, N, D))


class Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1, self.act, self.fc2 = nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim)

    def forward(self, x):
        return self.fc2(self.act(self.fc1(x)))


class Block(nn.Module):
    def __init__(self, dim: int, heads: int, mlp_ratio: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = Attention(dim, heads)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))

    def forward(self, x):
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class ViT(nn.Module):
    def __init__(self, image_size: int = 224, patch: int = 16, dim: int = 768, depth: int = 12, heads: int = 12,
                 mlp_ratio: float = 4.0):
        super().__init__()
        self.patch = patch
        self.patch_embed = PatchEmbed(patch, dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, dim))
        self.pos_embed = nn.Parameter(torch.randn(1, 1 + (image_size // patch) ** 2, dim) * 0.02)
        self.blocks = nn.ModuleList([Block(dim, heads, mlp_ratio) for _ in range(depth)])
        self.norm = nn.LayerNorm(dim, eps=1e-6)

    def _pos_embed(self, grid_h: int, grid_w: int) -> torch.Tensor:
        cls_pos, patch_pos = self.pos_embed[:, :1], self.pos_embed[:, 1:]
        side = int(math.isqrt(patch_pos.shape[1]))
        if (grid_h, grid_w) == (side, side):
            return self.pos_embed
        grid = patch_pos.reshape(1, side, side, -1).permute(0, 3, 1, 2)
        grid = F.interpolate(grid, size=(grid_h, grid_w), mode="bicubic", align_corners=False)
        return torch.cat([cls_pos, grid.permute(0, 2, 3, 1).reshape(1, grid_h * grid_w, -1)], dim=1)

    def forward_features(self, x: torch.Tensor, final_norm: bool = True) -> torch.Tensor:
        """x (B, 3, H, W) normalized -> tokens (B, 1 + P, D), CLS first."""
        B, _, H, W = x.shape
        tokens = self.patch_embed(x)
        tokens = torch.cat([self.cls_token.expand(B, -1, -1), tokens], dim=1)
        tokens = tokens + self._pos_embed(H // self.patch, W // self.patch)
        for block in self.blocks:
            tokens = block(tokens)
        return self.norm(tokens) if final_norm else tokens

    def cls(self, x):
        return self.forward_features(x, final_norm=True)[:, 0]

    def patch_tokens(self, x, final_norm: bool = True):
        return self.forward_features(x, final_norm=final_norm)[:, 1:]


def grid_pool(patch_tokens: torch.Tensor, n: int) -> torch.Tensor:
    """(B, P, D) square patch grid -> (B, n*n, D) by adaptive average pooling."""
    B, P, D = patch_tokens.shape
    side = int(math.isqrt(P))
    grid = patch_tokens.transpose(1, 2).reshape(B, D, side, side)
    return F.adaptive_avg_pool2d(grid, n).flatten(2).transpose(1, 2)


class ImageNetPreprocess(nn.Module):
    """The one place an image is normalized: uint8 (or [0, 1] float) NCHW -> resized, ImageNet-normalized.

    The study once normalized twice (torchvision transform + backbone processor), squeezing inputs to
    [-0.09, 1.04] and getting 0% success; a float input outside [0, 1] is refused rather than normalized again."""

    def __init__(self, size: int | None = 224):
        super().__init__()
        self.size = size
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dtype == torch.uint8:
            x = x.float() / 255.0
        elif x.numel() and (x.min() < -0.01 or x.max() > 1.01):
            raise ValueError(f"input already normalized (range [{x.min():.2f}, {x.max():.2f}]); "
                             "pass uint8 or [0, 1] images: normalization must happen exactly once")
        if self.size and x.shape[-2:] != (self.size, self.size):
            x = F.interpolate(x, size=(self.size, self.size), mode="bilinear", align_corners=False, antialias=True)
        return (x - self.mean) / self.std
