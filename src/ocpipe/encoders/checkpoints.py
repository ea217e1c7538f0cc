"""Loading the official DINO and SPOT weight files (strict key match) and writing files in those layouts.

No weights are downloaded: paths come from config, and a missing file names its config key and where
researchers get it. The writers exist so tests (and users converting weights) can produce both layouts."""

from __future__ import annotations

from pathlib import Path

import torch

from .slot_attention import SlotAttention
from .vit import ViT

DINO_URL = "https://dl.fbaipublicfiles.com/dino/dino_vitbase16_pretrain/dino_vitbase16_pretrain.pth"
SPOT_URL = "https://github.com/gkakogeorgiou/spot (released COCO checkpoint, checkpoint.pt.tar)"
# DINO training checkpoints wrap the backbone; the released file is flat. Prefixes seen in either layout:
_WRAPPERS = ("teacher", "student", "state_dict", "model")
_PREFIXES = ("module.", "backbone.")
_IGNORED_DINO = ("head.",)  # DINO projection head: not part of the backbone
# SPOT's model keeps its own ViT under encoder.*, the slot module under slot_attn.* (same names as ours, see
# slot_attention.py); the rest is the decoder and a frozen second encoder copy, unused for features.
SPOT_ENCODER, SPOT_SLOTS = "encoder.", "slot_attn."


class CheckpointError(ValueError):
    pass


def _require(path, config_key: str, where: str) -> Path:
    path = Path(path) if path else None
    if path is None or not path.is_file():
        raise FileNotFoundError(f"{config_key}: weight file not found: {path} (get it from {where}; it cannot be "
                                "downloaded by the offline workflow)")
    return path


def _strict_load(module: torch.nn.Module, state: dict, path: Path, what: str) -> None:
    own = module.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = [f"{k}: file {tuple(state[k].shape)} vs model {tuple(own[k].shape)}"
              for k in sorted(set(own) & set(state)) if state[k].shape != own[k].shape]
    if missing or unexpected or shapes:
        raise CheckpointError(f"{path}: not a {what} layout. missing keys {missing[:10]}; unexpected keys "
                              f"{unexpected[:10]}; shape mismatches {shapes[:10]}")
    module.load_state_dict(state, strict=True)


def _unwrap_dino(obj: dict) -> dict:
    for key in _WRAPPERS:
        if key in obj and isinstance(obj[key], dict):
            obj = obj[key]
            break
    out = {}
    for k, v in obj.items():
        for p in _PREFIXES:
            k = k.removeprefix(p)
        if not k.startswith(_IGNORED_DINO):
            out[k] = v
    return out


def load_dino_vit(path, config_key: str = "encoders.dino.checkpoint", **vit_kwargs) -> ViT:
    path = _require(path, config_key, DINO_URL)
    state = _unwrap_dino(torch.load(path, map_location="cpu", weights_only=False))
    vit = ViT(**vit_kwargs)
    _strict_load(vit, state, path, "DINO ViT")
    return vit.eval()


def load_spot(path, config_key: str = "encoders.spot.checkpoint", vit_kwargs: dict | None = None,
              slot_kwargs: dict | None = None) -> tuple[ViT, SlotAttention]:
    path = _require(path, config_key, SPOT_URL)
    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(ckpt, dict) or "model" not in ckpt:
        raise CheckpointError(f"{path}: a SPOT checkpoint is a dict with a 'model' state dict; found keys "
                              f"{list(ckpt)[:10] if isinstance(ckpt, dict) else type(ckpt).__name__}")
    model = {k.removeprefix("module."): v for k, v in ckpt["model"].items()}
    vit = ViT(**(vit_kwargs or {}))
    _strict_load(vit, {k[len(SPOT_ENCODER):]: v for k, v in model.items() if k.startswith(SPOT_ENCODER)}, path,
                 "SPOT encoder")
    sa = SlotAttention(**(slot_kwargs or {}))
    _strict_load(sa, {k[len(SPOT_SLOTS):]: v for k, v in model.items() if k.startswith(SPOT_SLOTS)}, path,
                 "SPOT slot_attn")
    return vit.eval(), sa.eval()


def write_dino_layout(vit: ViT, path) -> None:
    """The released DINO file: a flat state dict of the backbone."""
    torch.save({k: v.clone() for k, v in vit.state_dict().items()}, path)


def write_spot_layout(vit: ViT, slot_attention: SlotAttention, path, with_extras: bool = True) -> None:
    """SPOT's checkpoint.pt.tar: epoch / model / optimizer / best-metric keys; `model` holds encoder.*,
    slot_attn.* and (with_extras) a second encoder copy and decoder entries that loading must ignore."""
    model = {f"{SPOT_ENCODER}{k}": v.clone() for k, v in vit.state_dict().items()}
    model.update({f"{SPOT_SLOTS}{k}": v.clone() for k, v in slot_attention.state_dict().items()})
    if with_extras:
        model.update({f"second_encoder.{k}": v.clone() for k, v in vit.state_dict().items()})
        d = slot_attention.slots_init.weight.shape[1]
        model.update({"dec.layers.0.weight": torch.zeros(d, d), "input_proj.weight": torch.zeros(d, d),
                      "slot_proj.weight": torch.zeros(d, d), "bos_tokens": torch.zeros(1, 1, d)})
    torch.save({"epoch": 1, "model": model, "optimizer": {}, "best_val_ari": 0.0, "best_val_miou": 0.0}, path)
