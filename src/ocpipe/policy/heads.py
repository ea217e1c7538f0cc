"""Visual token heads: how a camera's K encoder tokens become policy tokens, and the two-camera fusion.

  tokens            every slot/patch token projected to the model width (K tokens per camera).
  flatten           the K tokens concatenated and projected: 1 token per camera (slot order matters).
  deepsets          rho(sum_k phi(x_k)): 1 permutation-invariant token per camera.
  weighted_pool     softmax-scored weighted mean of projected tokens: 1 token per camera.
  slot_transformer  2-layer self-attention over the K slots, then a mean: 1 token per camera.
Fusion `cross_attention`: each camera's tokens attend to the other camera's (both directions, residual)."""

from __future__ import annotations

import torch
from torch import nn


def mlp(sizes: list[int], act=nn.ReLU) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(act())
    return nn.Sequential(*layers)


class TokenHead(nn.Module):
    """(..., K, D) -> (..., K, W)."""

    def __init__(self, K: int, D: int, width: int, heads: int):
        super().__init__()
        self.proj = nn.Linear(D, width)
        self.tokens_out = K

    def forward(self, x):
        return self.proj(x)


class FlattenHead(nn.Module):
    def __init__(self, K: int, D: int, width: int, heads: int):
        super().__init__()
        self.proj = nn.Linear(K * D, width)
        self.tokens_out = 1

    def forward(self, x):
        return self.proj(x.flatten(-2))[..., None, :]


class DeepSetsHead(nn.Module):
    def __init__(self, K: int, D: int, width: int, heads: int):
        super().__init__()
        self.phi = mlp([D, width, width])
        self.rho = mlp([width, width, width])
        self.tokens_out = 1

    def forward(self, x):
        return self.rho(self.phi(x).sum(-2))[..., None, :]


class WeightedPoolHead(nn.Module):
    def __init__(self, K: int, D: int, width: int, heads: int):
        super().__init__()
        self.score = nn.Linear(D, 1)
        self.proj = nn.Linear(D, width)
        self.tokens_out = 1

    def forward(self, x):
        w = torch.softmax(self.score(x), dim=-2)
        return (w * self.proj(x)).sum(-2, keepdim=True)


class SlotTransformerHead(nn.Module):
    def __init__(self, K: int, D: int, width: int, heads: int):
        super().__init__()
        self.proj = nn.Linear(D, width)
        layer = nn.TransformerEncoderLayer(width, heads, 2 * width, dropout=0.0, batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, 2, enable_nested_tensor=False)
        self.tokens_out = 1

    def forward(self, x):
        lead = x.shape[:-2]
        y = self.encoder(self.proj(x).reshape(-1, *x.shape[-2:-1], self.proj.out_features))
        return y.mean(-2).reshape(*lead, 1, -1)


class NoVisualTokens(nn.Module):
    """(..., K, D) -> (..., 0, W): the policy sees the frozen tokens only through its object read-out."""

    def __init__(self, K: int, D: int, width: int, heads: int):
        super().__init__()
        self.width = width
        self.tokens_out = 0

    def forward(self, x):
        return x.new_zeros(*x.shape[:-2], 0, self.width)


HEADS = {"tokens": TokenHead, "flatten": FlattenHead, "deepsets": DeepSetsHead, "weighted_pool": WeightedPoolHead,
         "slot_transformer": SlotTransformerHead, "none": NoVisualTokens}


class CrossCameraFusion(nn.Module):
    """Bidirectional cross-attention between two cameras' tokens of the same timestep (no leak across time)."""

    def __init__(self, width: int, heads: int):
        super().__init__()
        self.a_from_b = nn.MultiheadAttention(width, heads, batch_first=True)
        self.b_from_a = nn.MultiheadAttention(width, heads, batch_first=True)
        self.norm_a, self.norm_b = nn.LayerNorm(width), nn.LayerNorm(width)

    def forward(self, x):
        """x (B, T, 2, K, W) -> same shape."""
        B, T, C, K, W = x.shape
        a, b = x[:, :, 0].reshape(B * T, K, W), x[:, :, 1].reshape(B * T, K, W)
        na, nb = self.norm_a(a), self.norm_b(b)
        a2 = a + self.a_from_b(na, nb, nb, need_weights=False)[0]
        b2 = b + self.b_from_a(nb, na, na, need_weights=False)[0]
        return torch.stack([a2, b2], dim=1).reshape(B, T, C, K, W)
