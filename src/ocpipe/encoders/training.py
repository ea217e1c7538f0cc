"""Training stage of the offline `slots_ssl` encoder: crops from frames stores in, frozen checkpoint out."""

from __future__ import annotations

import time
from dataclasses import fields
from pathlib import Path

import polars as pl
import torch

from ..frames.store import open_store
from ..util.atomic import atomic_path, write_json
from ..util.devices import pick_device
from . import crop, ssl_slots
from .decomposition import score_masks


def _split(store, holdout: int) -> tuple[int, int]:
    offsets = store.attrs["episode_offsets"]
    if holdout >= len(offsets) - 1:
        raise ValueError(f"encoders.slots_ssl.holdout_episodes={holdout} leaves no training episodes "
                         f"({len(offsets) - 1} in the store)")
    return 0, offsets[-1 - holdout]


def _crops(store, lo: int, hi: int, windows, grid: int, block: int = 1024) -> torch.Tensor:
    out = [crop.crop_and_resize(torch.from_numpy(store["rgb"][i : min(hi, i + block)]), windows, grid)
           for i in range(lo, hi, block)]
    x = torch.cat(out)  # (n, C, 3, g, g)
    return (x.flatten(0, 1) * 255).round().to(torch.uint8)


def train_stage(store_paths: list[str | Path], enc_cfg: dict, seed: int, out_ckpt: str | Path,
                out_curve: str | Path, out_eval: str | Path, threads: int = 1, progress: bool = True) -> dict:
    known = {f.name for f in fields(ssl_slots.SSLSlotsConfig)}
    cfg = ssl_slots.SSLSlotsConfig(**{k: v for k, v in enc_cfg.items() if k in known}, seed=seed)
    images, held_out = [], []
    for path in store_paths:
        store = open_store(path)
        a = store.attrs.asdict()
        windows = crop.crop_windows(store["cam_intrinsic"][...], store["cam_extrinsic"][...], a["resolution"],
                                    enc_cfg["workspace_min"], enc_cfg["workspace_max"])
        lo, hi = _split(store, enc_cfg["holdout_episodes"])
        images.append(_crops(store, lo, hi, windows, cfg.grid))
        held_out.append((path, store, windows, hi))
    images = torch.cat(images)
    t0 = time.perf_counter()
    model, curve, _ = ssl_slots.train(images, cfg, threads=threads, progress=progress,
                                      device=pick_device(enc_cfg["device"]))
    train_seconds = time.perf_counter() - t0
    with atomic_path(out_ckpt) as tmp:
        ssl_slots.save(
            model,
            tmp,
            {
                "workspace_min": enc_cfg["workspace_min"],
                "workspace_max": enc_cfg["workspace_max"],
                "train_stores": [str(p) for p in store_paths],
                "train_images": len(images),
                # no wall time in here (held_out_decomposition.json has it): the checkpoint's sha256 is its
                # identity, and it must not change between two runs that trained the same weights
            },
        )
    with atomic_path(out_curve) as tmp:
        pl.DataFrame(curve).write_parquet(tmp)
    # decomposition on episodes the encoder never saw
    scores = {}
    for path, store, windows, hi in held_out:
        a = store.attrs.asdict()
        n = store["rgb"].shape[0]
        x = crop.crop_and_resize(torch.from_numpy(store["rgb"][hi:n]), windows, cfg.grid)
        with torch.inference_mode():
            _, masks = model.encode(x.flatten(0, 1))
        masks = masks.reshape(n - hi, len(a["cameras"]), *masks.shape[1:]).numpy()
        scores[Path(path).stem] = {
            "frames": n - hi,
            "episodes": enc_cfg["holdout_episodes"],
            **score_masks(masks, store["seg"][hi:n], windows, a["segmentation_ids"], a["task"], a["cameras"]),
        }
    report = {
        "train_seconds": train_seconds,
        "train_images": len(images),
        "steps": cfg.steps,
        "final_loss": curve[-1]["loss"],
        "final_mask_entropy": curve[-1]["mask_entropy"],
        "held_out": scores,
    }
    write_json(out_eval, report)
    return report
