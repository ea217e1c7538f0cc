"""Where torch work runs: CUDA when present and allowed by config (`auto`), else CPU."""

from __future__ import annotations

import torch


def pick_device(setting: str) -> torch.device:
    """'auto' | 'cpu' | 'cuda' (a config `device` key) -> the torch device to use."""
    if setting == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("device is 'cuda' but torch sees no CUDA device (use 'auto' or 'cpu')")
    return torch.device("cuda" if setting in ("auto", "cuda") and torch.cuda.is_available() else "cpu")


def to_device(encoder, device: torch.device):
    """Move a frozen encoder's torch modules to ``device`` (its encode() then expects inputs there)."""
    for value in vars(encoder).values():
        if isinstance(value, torch.nn.Module):
            value.to(device)
    return encoder
