"""Fitting the statistics of the visual tokens and the object read-out: what the Normalizer cannot fit from the
labels alone, because it reads the features store (a chunk at a time) or the scenes store."""

from __future__ import annotations

import logging

import numpy as np
import torch

from ..features.probes import fit_mse
from . import normalization, observation

log = logging.getLogger(__name__)


def gather_tokens(tokens, frames: np.ndarray, block: int = 1024) -> np.ndarray:
    """The tokens of sorted frame ids ``frames``, read a block of frames at a time (a token store decompresses
    whole chunks: one read per frame would decompress a chunk per frame)."""
    return np.concatenate([tokens[lo : lo + block][frames[(frames >= lo) & (frames < lo + block)] - lo]
                           for lo in range(0, int(frames[-1]) + 1, block)])


def spread(frames: np.ndarray, max_frames: int = 20000) -> np.ndarray:
    """At most ``max_frames`` evenly spaced of ``frames``."""
    return frames[np.unique(np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int))]


def element_stats(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean/std of every element of (N, ...) inputs, flattened per sample."""
    return normalization.fit(x.reshape(len(x), -1).astype(np.float64))


def fit_tokens(norm: normalization.Normalizer, policy, tokens, train_frames: np.ndarray) -> None:
    """The visual tokens' statistics (token_norm: per dimension, pooled over cameras and slots) and, for a read-out
    standardized per element without the scenes store, its input's, on evenly spaced training frames."""
    if policy.visual.token_norm == "zscore":
        x = gather_tokens(tokens, spread(train_frames))
        norm.tokens.set(*element_stats(x.reshape(-1, x.shape[-1])))
    if norm.readout_elementwise and not policy.readout.scenes:  # else fit_readout sets them
        norm.readout.set(*element_stats(gather_tokens(tokens, spread(train_frames))[:, list(policy.stores.cameras)]))


def readout_weights(yaw_weight: float, device=None) -> torch.Tensor:
    """The object read-out's per-output loss weights: position 1, the yaw's sin/cos ``yaw_weight``."""
    return torch.tensor([1.0, 1.0, 1.0, yaw_weight, yaw_weight], device=device)


def fit_readout(model, policy, tokens, pose: np.ndarray, train_frames: np.ndarray, scenes, seed: int,
                epochs: int = 40, batch: int = 256) -> float:
    """Fit the policy's object read-out on the training demos' frames (their raw poses ``pose``, (N, 5)) plus the
    scenes store's scenes, then freeze it: the policy trains around a fixed estimate of where the object is,
    fitted on far more placements than the demos show. -> the last batch's loss."""
    cams, norm = list(policy.stores.cameras), model.normalizer
    demo = gather_tokens(tokens, train_frames)[:, cams].astype(np.float32)
    scene_pose = observation.object_pose({"obj_pos": scenes["obj_pos"][...], "obj_quat": scenes["obj_quat"][...]})
    y = np.concatenate([pose[train_frames], scene_pose])
    x = np.concatenate([demo, scenes["tokens"][...][:, cams].astype(np.float32)])
    device = norm.tokens.mean.device
    if norm.readout_elementwise:  # the input statistics of what the read-out is fitted on: demos and scenes
        norm.readout.set(*element_stats(x))
    with torch.no_grad():
        xz = norm.readout_input(torch.from_numpy(x).to(device))
        yt = norm.pose(torch.from_numpy(y.astype(np.float32)).to(device))
    readout = model.object_readout
    loss = fit_mse(readout, xz, yt, torch.Generator().manual_seed(seed), epochs, batch,
                   weights=readout_weights(policy.readout.yaw_weight, device))
    readout.requires_grad_(False)
    log.info("object read-out fitted on %d demo frames and %d scenes, then frozen (loss %.4f)", len(demo),
             len(x) - len(demo), loss)
    return loss
