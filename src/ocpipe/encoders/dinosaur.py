"""SPOT's slot module trained on our frames on top of a frozen DINO ViT (DINOSAUR-style), for users who have
DINO weights but not SPOT's checkpoint: Slot Attention (768 -> 7 x 256) is trained to reconstruct the frozen
patch features through a per-slot MLP decoder with alpha mixing."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
from tqdm import tqdm

from .slot_attention import SlotAttention
from .vit import ImageNetPreprocess

SLOT_KWARGS = dict(input_dim=768, slot_dim=256, num_slots=7, iterations=3, mlp_hidden_dim=1024)


class FeatureDecoder(nn.Module):
    """Broadcast each slot over the patch grid (+ learned position), MLP -> feature + alpha; mix by softmax."""

    def __init__(self, slot_dim: int, feature_dim: int, num_patches: int, hidden: int = 1024):
        super().__init__()
        self.pos = nn.Parameter(torch.randn(1, 1, num_patches, slot_dim) * 0.02)
        self.mlp = nn.Sequential(nn.Linear(slot_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, feature_dim + 1))

    def forward(self, slots):
        out = self.mlp(slots[:, :, None] + self.pos)  # (B, K, P, D+1)
        alpha = out[..., -1:].softmax(dim=1)
        return (alpha * out[..., :-1]).sum(1)


def train_slot_module(vit, images_u8: torch.Tensor, image_size: int, steps: int, batch_size: int, lr: float,
                      seed: int, threads: int = 1, slot_kwargs: dict | None = None, progress: bool = True,
                      device: torch.device | str = "cpu"):
    """images_u8 (M, 3, H, W). Returns (slot module on CPU, curve rows)."""
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    kwargs = dict(SLOT_KWARGS, **(slot_kwargs or {}))
    vit = vit.eval().to(device)
    prep = ImageNetPreprocess(image_size).to(device)
    sa = SlotAttention(**kwargs).to(device)
    with torch.no_grad():
        probe = vit.forward_features(prep(images_u8[:1].to(device)), final_norm=False)
    dec = FeatureDecoder(kwargs["slot_dim"], probe.shape[-1], probe.shape[1] - 1).to(device)
    opt = torch.optim.Adam([*sa.parameters(), *dec.parameters()], lr=lr)
    gen = torch.Generator().manual_seed(seed)
    curve, t0 = [], time.perf_counter()
    for step in tqdm(range(steps), desc="train SPOT slot module on DINO", disable=not progress):
        idx = torch.randint(len(images_u8), (batch_size,), generator=gen)
        with torch.no_grad():
            target = vit.forward_features(prep(images_u8[idx].to(device)), final_norm=False)[:, 1:]
        slots, _ = sa(target)
        loss = ((dec(slots) - target) ** 2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        curve.append({"step": step, "loss": loss.item(), "seconds": time.perf_counter() - t0})
    return sa.eval().cpu(), curve


def save_slot_module(sa: SlotAttention, path: str | Path, meta: dict) -> None:
    # a file object keeps the temporary file's name out of the archive (see ssl_slots.save)
    with open(path, "wb") as fh:
        torch.save({"encoder": "spot_slots_on_dino", "slot_kwargs": meta.get("slot_kwargs", SLOT_KWARGS),
                    "state_dict": sa.state_dict(), **meta}, fh)


def load_slot_module(path: str | Path) -> SlotAttention:
    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    if ckpt.get("encoder") != "spot_slots_on_dino":
        raise ValueError(f"{path} is not a slot module trained on DINO (encoder={ckpt.get('encoder')!r})")
    sa = SlotAttention(**ckpt["slot_kwargs"])
    sa.load_state_dict(ckpt["state_dict"])
    return sa.eval()


def frames_sample(store, n: int) -> torch.Tensor:
    """n frames (all cameras) drawn evenly from a frames store -> (n*C, 3, H, W) uint8."""
    N = store["rgb"].shape[0]
    idx = np.unique(np.linspace(0, N - 1, min(n, N)).round().astype(int))
    rgb = torch.from_numpy(store["rgb"].get_orthogonal_selection((idx,)))
    return rgb.flatten(0, 1).permute(0, 3, 1, 2).contiguous()
