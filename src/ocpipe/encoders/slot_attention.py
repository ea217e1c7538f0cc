"""Slot Attention (Locatello et al. 2020) with deterministic learned initial slots, laid out like SPOT's
`slot_attn` module so its released weights load by name (checked against SPOT's slot_attn.py):

    layer_norm, mlp.{0,2}            input LayerNorm + MLP over the ViT features
    slots_init.weight [K, D]         learned per-slot initial queries (no sampling: same input, same slots)
    slot_attention.norm_inputs       a second LayerNorm before the k/v projections (optional: see slots_ssl)
    slot_attention.project_{q,k,v}   no bias
    slot_attention.gru               GRUCell(D, D)
    slot_attention.norm_slots, .norm_mlp, .mlp.{0,2}   residual MLP D -> hidden -> D

Slots are queries and inputs keys/values; the softmax runs over the slot axis so slots compete for each input,
then each slot takes the attention-weighted mean of the values."""

from __future__ import annotations

import torch
import torch.nn as nn


class _Iterations(nn.Module):
    def __init__(self, input_dim: int, slot_dim: int, mlp_hidden_dim: int, iterations: int, eps: float,
                 norm_inputs: bool):
        super().__init__()
        self.iterations, self.eps, self.slot_dim = iterations, eps, slot_dim
        self.norm_inputs = nn.LayerNorm(input_dim) if norm_inputs else nn.Identity()
        self.norm_slots = nn.LayerNorm(slot_dim)
        self.norm_mlp = nn.LayerNorm(slot_dim)
        self.project_q = nn.Linear(slot_dim, slot_dim, bias=False)
        self.project_k = nn.Linear(input_dim, slot_dim, bias=False)
        self.project_v = nn.Linear(input_dim, slot_dim, bias=False)
        self.gru = nn.GRUCell(slot_dim, slot_dim)
        self.mlp = nn.Sequential(nn.Linear(slot_dim, mlp_hidden_dim), nn.ReLU(), nn.Linear(mlp_hidden_dim, slot_dim))

    def forward(self, inputs: torch.Tensor, slots: torch.Tensor, value_inputs: torch.Tensor | None = None):
        B, K, D = slots.shape
        x = self.norm_inputs(inputs)
        k = self.project_k(x) * D**-0.5
        v = self.project_v(x if value_inputs is None else self.norm_inputs(value_inputs))
        attn = None
        for _ in range(self.iterations):
            q = self.project_q(self.norm_slots(slots))
            attn = torch.softmax(torch.einsum("bkd,bnd->bkn", q, k), dim=1)  # over slots
            weights = (attn + self.eps) / (attn + self.eps).sum(dim=-1, keepdim=True)  # mean over inputs
            updates = torch.einsum("bkn,bnd->bkd", weights, v)
            slots = self.gru(updates.reshape(-1, D), slots.reshape(-1, D)).reshape(B, K, D)
            slots = slots + self.mlp(self.norm_mlp(slots))
        return slots, attn


class SlotAttention(nn.Module):
    def __init__(self, input_dim: int = 768, slot_dim: int = 256, num_slots: int = 7, iterations: int = 3,
                 mlp_hidden_dim: int = 1024, eps: float = 1e-8, norm_inputs: bool = True):
        super().__init__()
        self.num_slots = num_slots
        self.layer_norm = nn.LayerNorm(input_dim)
        self.mlp = nn.Sequential(nn.Linear(input_dim, input_dim), nn.ReLU(), nn.Linear(input_dim, input_dim))
        self.slots_init = nn.Embedding(num_slots, slot_dim)
        nn.init.xavier_uniform_(self.slots_init.weight)
        self.slot_attention = _Iterations(input_dim, slot_dim, mlp_hidden_dim, iterations, eps, norm_inputs)

    def forward(self, inputs: torch.Tensor, init_slots: torch.Tensor | None = None,
                value_inputs: torch.Tensor | None = None):
        """inputs (B, N, input_dim) -> slots (B, K, slot_dim), attention masks (B, K, N) summing to 1 over K.

        ``value_inputs`` (same shape), when given, feed the values instead of ``inputs``: what groups the inputs
        (keys) and what the slots carry (values) can then differ."""
        B = inputs.shape[0]
        slots = (self.slots_init.weight if init_slots is None else init_slots).expand(B, -1, -1)
        embed = lambda t: self.mlp(self.layer_norm(t))  # noqa: E731
        values = None if value_inputs is None else embed(value_inputs)
        return self.slot_attention(embed(inputs), slots, values)
