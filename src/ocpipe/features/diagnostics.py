"""Diagnostics of a features store: the thesis' slot statistics and decomposition against segmentation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..encoders import slot_metrics
from ..encoders.decomposition import score_masks
from ..frames.store import open_store
from . import probes
from .encode import open_features

MAX_DIAGNOSTIC_FRAMES = 4000  # mask statistics on an evenly spaced sample: they are means, the sample is plenty


def diagnostics(frames_path: str | Path, features_path: str | Path, holdout_episodes: int | None,
                probe_holdout: float = 0.15, probe_mlp_epochs: int = 150, seed: int = 0) -> dict:
    """``holdout_episodes``: score decomposition only on the store's last episodes (those the encoder did not
    train on); None scores every frame (a store the encoder never saw). ``probe_*``: the position probes of
    ``probes.probe`` (``probe_mlp_epochs`` 0: ridge alone)."""
    frames, feats = open_store(frames_path), open_features(features_path)
    fa = frames.attrs.asdict()
    tokens = feats["tokens"]
    N = tokens.shape[0]
    out = {"encoder": feats.attrs["encoder"], "frames": N, "tokens_shape": list(tokens.shape[1:]),
           "encode_frames_per_second": feats.attrs.get("frames_per_second"),
           "temporal_embedding_diversity": slot_metrics.temporal_diversity(tokens[...].astype(np.float32),
                                                                           frames["episode_index"][...])}
    episode_index = frames["episode_index"][...]
    if len(np.unique(episode_index)) >= 2:
        out["probes"] = probes.probe(tokens[...], {name: frames[name][...] for name in probes.TARGETS
                                                   if name in frames}, episode_index, probe_holdout, seed,
                                     probe_mlp_epochs)
    if "masks" not in feats:
        return out
    sample = np.unique(np.linspace(0, N - 1, min(N, MAX_DIAGNOSTIC_FRAMES)).round().astype(int))
    masks = feats["masks"].get_orthogonal_selection((sample,)).astype(np.float32)
    out["mask_diagnostics"] = {cam: slot_metrics.mask_diagnostics(masks[:, c]) for c, cam in enumerate(fa["cameras"])}
    offsets = fa["episode_offsets"]
    lo = offsets[-1 - holdout_episodes] if holdout_episodes else 0
    windows = np.array(feats.attrs["crop_windows"]) if "crop_windows" in feats.attrs else None
    out["decomposition"] = {
        "frames": N - lo, "scored_on": "held-out episodes" if holdout_episodes else "all frames (never trained on)",
        **score_masks(feats["masks"][lo:N].astype(np.float32), frames["seg"][lo:N], windows, fa["segmentation_ids"],
                      fa["task"], fa["cameras"]),
    }
    return out
