"""The features stage: encode every frame of a frames store with a frozen encoder into a features store.

Features are stored per frame (the thesis stored 5x-duplicated windows); the policy's loader builds windows by
index. Layout of ``results/features/{task}_{cams}_{res}_{encoder}.zarr``:
  tokens (N, C, K, D) float16   visual tokens per camera
  masks  (N, C, K, h, w) float16 slot attention masks (slot encoders only)
  attrs: encoder, checkpoint_sha256, frames_store, frames_store_attrs (task, cameras, resolution, episode_*),
         and the encoder's own (slots_ssl: crop_windows, the (x0, y0, size) pixel window each mask covers)."""

from __future__ import annotations

import hashlib
import time
from pathlib import Path
from typing import Protocol

import torch
import zarr
from tqdm import tqdm

from ..frames.store import open_store
from ..util.atomic import atomic_path
from ..util.devices import pick_device, to_device


class FrozenEncoder(Protocol):
    name: str
    checkpoint: Path | None

    def encode(self, rgb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """rgb (B, C, H, W, 3) uint8 -> tokens (B, C, K, D), masks (B, C, K, h, w) or None."""


def sha256(path: str | Path | None) -> str | None:
    if path is None:
        return None
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def encode_store(encoder: FrozenEncoder, frames_path: str | Path, out_path: str | Path, batch_size: int,
                 chunk_frames: int, threads: int = 1, dtype: str = "float16", progress: bool = True,
                 device: str = "auto") -> dict:
    torch.set_num_threads(threads)
    dev = pick_device(device)
    encoder = to_device(encoder, dev)
    reads_labels = getattr(encoder, "reads_labels", False)
    frames = open_store(frames_path, need=("obj_pos",) if reads_labels else ("rgb",))
    if reads_labels:
        return _write_label_tokens(encoder, frames, frames_path, out_path, chunk_frames)
    rgb = frames["rgb"]
    N = rgb.shape[0]
    t0 = time.perf_counter()
    with atomic_path(out_path) as tmp, torch.inference_mode():
        root = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        tokens_arr = masks_arr = None
        bar = tqdm(
            total=N, desc=f"encode {Path(frames_path).name} [{encoder.name}]", unit="frame", disable=not progress
        )
        # read one store chunk at a time (a frames chunk is the unit of I/O), encode it in batches
        step = rgb.chunks[0] * max(1, batch_size // rgb.chunks[0])
        for lo in range(0, N, step):
            block = torch.from_numpy(rgb[lo : lo + step]).to(dev)
            outs = [encoder.encode(block[i : i + batch_size]) for i in range(0, len(block), batch_size)]
            tokens = torch.cat([o[0] for o in outs]).cpu().numpy().astype(dtype)
            masks = None
            if outs[0][1] is not None:
                masks = torch.cat([o[1] for o in outs]).cpu().numpy().astype(dtype)
            if tokens_arr is None:
                tokens_arr = root.create_array(
                    "tokens", shape=(N, *tokens.shape[1:]), dtype=dtype, chunks=(chunk_frames, *tokens.shape[1:])
                )
                if masks is not None:
                    masks_arr = root.create_array(
                        "masks", shape=(N, *masks.shape[1:]), dtype=dtype, chunks=(chunk_frames, *masks.shape[1:])
                    )
            tokens_arr[lo : lo + len(tokens)] = tokens
            if masks_arr is not None:
                masks_arr[lo : lo + len(masks)] = masks
            bar.update(len(block))
        bar.close()
        seconds = time.perf_counter() - t0
        root.attrs.update(
            {
                **_provenance(encoder, frames, frames_path),
                "encode_seconds": seconds,
                "frames_per_second": N / seconds,
                **getattr(encoder, "extra_attrs", {}),
            }
        )
    return {"frames": N, "seconds": seconds, "frames_per_second": N / seconds}


def _provenance(encoder, frames: zarr.Group, frames_path) -> dict:
    fa = frames.attrs.asdict()
    return {
        "encoder": encoder.name,
        "checkpoint": str(encoder.checkpoint) if encoder.checkpoint else None,
        "checkpoint_sha256": sha256(encoder.checkpoint),
        "frames_store": str(frames_path),
        "frames_store_attrs": {k: fa[k] for k in PROVENANCE_KEYS if k in fa},
    }


def _write_label_tokens(encoder, frames: zarr.Group, frames_path, out_path, chunk_frames: int) -> dict:
    """Encoders that read the simulator's labels (the privileged-state control) instead of images."""
    tokens = encoder.tokens_from_store(frames)
    with atomic_path(out_path) as tmp:
        root = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        root.create_array("tokens", shape=tokens.shape, dtype="float32", chunks=(chunk_frames, *tokens.shape[1:]))
        root["tokens"][...] = tokens
        root.attrs.update({**_provenance(encoder, frames, frames_path), **getattr(encoder, "extra_attrs", {})})
    return {"frames": len(tokens), "seconds": 0.0, "frames_per_second": None}


def open_features(path: str | Path) -> zarr.Group:
    path = Path(path)
    if not (path / "zarr.json").is_file():
        raise FileNotFoundError(f"no features store at {path}")
    root = zarr.open_group(str(path), mode="r", zarr_format=3)
    if "tokens" not in root:
        raise ValueError(
            f"{path}: features store has no 'tokens' array (damaged or cut short): delete it and rerun "
            "the workflow to rebuild it"
        )
    return root


PROVENANCE_KEYS = ("task", "camera_set", "cameras", "resolution", "episode_seeds", "episode_offsets")


def check_provenance(feats: zarr.Group, features_path, frames: zarr.Group, frames_path) -> None:
    """Refuse a features store encoded from another frames store than ``frames`` (rows would pair the wrong
    frames' tokens with these labels). Stores without recorded provenance pass."""
    recorded = feats.attrs.get("frames_store_attrs")
    if not recorded:
        return
    fa = frames.attrs.asdict()
    differ = [k for k in PROVENANCE_KEYS if k in recorded and k in fa and recorded[k] != fa[k]]
    if differ:

        def short(v):
            text = repr(v)
            return text if len(text) <= 40 else text[:37] + "..."

        what = "; ".join(f"{k}: {short(recorded[k])} there, {short(fa[k])} here" for k in differ)
        raise ValueError(
            f"{features_path} was encoded from {feats.attrs.get('frames_store', 'another frames store')}, "
            f"not from {frames_path} ({what}): delete the features store and rerun the workflow to "
            "rebuild it from this frames store"
        )
