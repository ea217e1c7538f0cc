"""A policy checkpoint, written and read: the model's state dict (weights and the Normalizer's statistics), the
resolved policy settings as a plain dict, what it was trained on (meta), the epoch and training history, and,
for resuming, the optimizer's state. Evaluation reads checkpoints through this module alone."""

from __future__ import annotations

from pathlib import Path

import torch

from ..util.atomic import atomic_path
from .model import SequencePolicy
from .settings import PolicySettings


def build_model(policy: PolicySettings | dict, meta: dict) -> SequencePolicy:
    return SequencePolicy(policy, meta["K"], meta["D"])


def save(state: dict, path: Path) -> None:
    # through a file object: given a path, torch.save names the archive inside after the temporary file
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        torch.save(state, fh)


def load_policy(path, device: str | torch.device = "cpu") -> tuple[SequencePolicy, PolicySettings, dict]:
    """A saved checkpoint -> (model in eval mode, its policy settings, meta)."""
    ckpt = torch.load(path, map_location=device, weights_only=False)
    policy = PolicySettings.of(ckpt["policy"])
    if not any(k.startswith("normalizer.") for k in ckpt["model"]):
        raise ValueError(f"{path}: a checkpoint from before the policy kept its statistics in the model; delete "
                         f"{Path(path).parent.parent} and rerun the workflow to retrain it")
    model = build_model(policy, ckpt["meta"]).to(device)
    model.load_state_dict(ckpt["model"])
    model.eval()
    return model, policy, ckpt["meta"]
