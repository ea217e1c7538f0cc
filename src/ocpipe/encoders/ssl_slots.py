"""`slots_ssl`: the offline default encoder. Slot Attention (K slots, deterministic learned initial queries) over
per-cell features of each camera's workspace crop, trained self-supervised on the rendered frames, then frozen.

Why this shape, on a 2-core CPU budget (a plain Slot Attention autoencoder failed there: docs/study.md, Encoders):
- Input is the workspace crop (encoders/crop.py) at a small grid, so the cube covers a few cells, not 2x2 px.
- The decoder has no per-pixel network: every slot predicts one appearance (a colour plus a linear shading
  gradient), so a training step costs little more than the encoder. The loss is the reconstruction error
  *expected under the slot attention*, sum_k m_k(x) |x - a_k(x)|^2 (a Gaussian-mixture / k-means objective),
  not the error of the mixed image |x - sum_k m_k(x) a_k(x)|^2: with the latter, soft masks rebuild any colour
  as a convex mix of slot colours (seen: near-zero loss with masks at maximum entropy, no decomposition). The
  only way to lower this loss is to hand each region of one appearance to one slot, and objects in these scenes
  are such regions (red cube, green marker, grey robot, textured table).
- The reconstruction error of each pixel is weighted by a power (rarity_power) of its colour's inverse frequency in
  the training frames, so the few saturated cube and marker pixels count as much as the large table area.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import torch
import torch.nn as nn
from tqdm import tqdm

from .slot_attention import SlotAttention

COLOUR_LEVELS = 8  # per-channel quantization of the rarity histogram (512 bins)


@dataclass
class SSLSlotsConfig:
    num_slots: int = 7
    slot_dim: int = 64
    feature_dim: int = 64
    grid: int = 48
    iterations: int = 3
    steps: int = 3000
    batch_size: int = 32
    lr: float = 4e-4
    warmup_steps: int = 200
    seed: int = 0
    rarity_clip: float = 30.0
    rarity_power: float = 0.5
    position_in_keys: bool = True


def _grid_coords(grid: int) -> torch.Tensor:
    ys, xs = torch.meshgrid(torch.linspace(0, 1, grid), torch.linspace(0, 1, grid), indexing="ij")
    return torch.stack([xs, ys], dim=-1).reshape(grid * grid, 2)


class SSLSlotEncoder(nn.Module):
    def __init__(self, cfg: SSLSlotsConfig):
        super().__init__()
        self.cfg = cfg
        d = cfg.feature_dim
        self.cnn = nn.Sequential(
            nn.Conv2d(3, d, 3, padding=1), nn.ReLU(),
            nn.Conv2d(d, d, 3, padding=1), nn.ReLU(),
            nn.Conv2d(d, d, 3, padding=1),
        )
        self.register_buffer("coords", _grid_coords(cfg.grid), persistent=False)
        self.pos = nn.Linear(4, d)
        self.colour = nn.Linear(3, d)  # raw colour as a direct input: it is the strongest object cue here
        # no second LayerNorm before k/v (SPOT has one): on these colour-coded cells it normalizes away the
        # colour contrast, and the cube lost its slot (held-out cube IoU 0.03 with it vs 0.17 without, 500 steps)
        self.slot_attention = SlotAttention(input_dim=d, slot_dim=cfg.slot_dim, num_slots=cfg.num_slots,
                                            iterations=cfg.iterations, mlp_hidden_dim=4 * cfg.slot_dim,
                                            norm_inputs=False)
        # appearance of a slot: RGB + d(RGB)/dx + d(RGB)/dy
        self.appearance = nn.Sequential(nn.Linear(cfg.slot_dim, cfg.slot_dim), nn.ReLU(), nn.Linear(cfg.slot_dim, 9))

    def encode(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """images (B, 3, g, g) in [0, 1] -> slots (B, K, D), masks (B, K, g, g) summing to 1 over slots."""
        B, g = images.shape[0], self.cfg.grid
        x = self.cnn(images * 2 - 1).flatten(2).transpose(1, 2)  # (B, g*g, d)
        c = self.coords
        x = x + self.colour(images.flatten(2).transpose(1, 2))
        xp = x + self.pos(torch.cat([c, 1 - c], dim=-1))
        if self.cfg.position_in_keys:
            slots, masks = self.slot_attention(xp)
        else:
            slots, masks = self.slot_attention(x, value_inputs=xp)
        return slots, masks.reshape(B, -1, g, g)

    def appearances(self, slots: torch.Tensor) -> torch.Tensor:
        """slots (B, K, D) -> each slot's image (B, K, 3, g, g)."""
        B, K = slots.shape[:2]
        app = self.appearance(slots)  # (B, K, 9)
        colour, gx, gy = app[..., 0:3], app[..., 3:6], app[..., 6:9]
        c = self.coords - 0.5  # (P, 2)
        per_slot = colour[:, :, None] + gx[:, :, None] * c[None, None, :, :1] + gy[:, :, None] * c[None, None, :, 1:]
        return per_slot.transpose(2, 3).reshape(B, K, 3, self.cfg.grid, self.cfg.grid)

    def forward(self, images):
        slots, masks = self.encode(images)
        return slots, masks, self.appearances(slots)


def colour_bins(images_u8: torch.Tensor) -> torch.Tensor:
    """(B, 3, g, g) uint8 -> (B, g, g) bin index of each pixel's quantized colour."""
    q = (images_u8.long() * COLOUR_LEVELS) // 256
    return (q[:, 0] * COLOUR_LEVELS + q[:, 1]) * COLOUR_LEVELS + q[:, 2]


def rarity_weights(images_u8: torch.Tensor, clip: float, power: float = 0.5) -> torch.Tensor:
    """Weight per colour bin: frequency^-power, normalized to mean 1 over the training pixels, capped at ``clip``."""
    counts = torch.bincount(colour_bins(images_u8).flatten(), minlength=COLOUR_LEVELS**3).double()
    freq = counts / counts.sum()
    w = torch.where(counts > 0, freq.clamp_min(1e-12) ** -power, torch.zeros_like(freq))
    w = w / (w * freq).sum()
    return w.clamp(max=clip).float()


def train(images_u8: torch.Tensor, cfg: SSLSlotsConfig, threads: int = 1, progress: bool = True,
          device: torch.device | str = "cpu"):
    """Train on crops (M, 3, g, g) uint8. Returns (model on CPU, curve rows, weights). Deterministic for a seed on
    CPU."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(threads)
    model = SSLSlotEncoder(cfg).to(device)
    weights = rarity_weights(images_u8, cfg.rarity_clip, cfg.rarity_power).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, (s + 1) / cfg.warmup_steps)
                                              * 0.5 * (1 + math.cos(math.pi * min(1.0, s / cfg.steps))))
    gen = torch.Generator().manual_seed(cfg.seed)
    curve, t0 = [], time.perf_counter()
    bar = tqdm(range(cfg.steps), desc="train slots_ssl", disable=not progress)
    for step in bar:
        idx = torch.randint(len(images_u8), (cfg.batch_size,), generator=gen)
        batch_u8 = images_u8[idx].to(device)
        x = batch_u8.float() / 255.0
        _, masks, per_slot = model(x)
        w = weights[colour_bins(batch_u8)]  # (B, g, g)
        err = ((per_slot - x[:, None]) ** 2).sum(2)  # (B, K, g, g)
        loss = (w * (masks * err).sum(1)).mean()
        with torch.no_grad():
            recon_loss = (w * ((masks[:, :, None] * per_slot).sum(1) - x).pow(2).sum(1)).mean()
            entropy = -(masks * torch.log(masks.clamp_min(1e-8))).sum(1).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
        if step % 10 == 0 or step == cfg.steps - 1:
            curve.append(
                {
                    "step": step,
                    "loss": loss.item(),
                    "mixed_recon": recon_loss.item(),
                    "mask_entropy": entropy.item(),
                    "lr": sched.get_last_lr()[0],
                    "seconds": time.perf_counter() - t0,
                }
            )
            bar.set_postfix(loss=f"{loss.item():.4f}", H=f"{entropy.item():.2f}")
    model.eval()
    return model.cpu(), curve, weights.cpu()


def save(model: SSLSlotEncoder, path, extra: dict) -> None:
    # through a file object: given a path, torch.save names the archive inside the file after it, and writers pass
    # a temporary .tmp-<pid>-model.pt; the bytes, and the sha256 that features stores and policies record, would
    # then differ between two runs that trained the same weights
    with open(path, "wb") as fh:
        torch.save({"encoder": "slots_ssl", "config": asdict(model.cfg), "state_dict": model.state_dict(), **extra},
                   fh)


def load(path) -> tuple[SSLSlotEncoder, dict]:
    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    if ckpt.get("encoder") != "slots_ssl":
        raise ValueError(f"{path} is not a slots_ssl checkpoint (encoder={ckpt.get('encoder')!r})")
    model = SSLSlotEncoder(SSLSlotsConfig(**ckpt["config"]))
    model.load_state_dict(ckpt["state_dict"])
    model.eval()
    return model, ckpt
