"""Per-slot attention maps for both cameras on chosen (trajectory, step) pairs (the thesis' appendix E)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..frames.store import open_store
from ..util.atomic import atomic_path
from .encode import open_features


def _crop(img: np.ndarray, window) -> np.ndarray:
    x0, y0, size = (int(v) for v in window)
    return img[y0 : y0 + size, x0 : x0 + size]


def attention_maps(frames_path: str | Path, features_path: str | Path, pairs: list[tuple[int, int]],
                   out_png: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames, feats = open_store(frames_path), open_features(features_path)
    if "masks" not in feats:
        raise ValueError(
            f"{features_path} has no slot masks (encoder {feats.attrs['encoder']!r} is not a slot encoder)"
        )
    fa, windows = frames.attrs.asdict(), feats.attrs.get("crop_windows")
    offsets, cams = fa["episode_offsets"], fa["cameras"]
    K = feats["masks"].shape[2]
    rows = [(t, s, c) for t, s in pairs for c in range(len(cams))]
    # column 1: every cell coloured by its argmax slot, so which objects share a slot is visible at a glance
    palette = plt.get_cmap("tab10")(np.arange(K) % 10)[:, :3]
    fig, axes = plt.subplots(len(rows), K + 2, figsize=(1.3 * (K + 2), 1.4 * len(rows)), squeeze=False)
    for r, (traj, step, c) in enumerate(rows):
        if not 0 <= traj < len(offsets) - 1:
            raise ValueError(f"trajectory {traj} not in {frames_path} ({len(offsets) - 1} episodes)")
        length = offsets[traj + 1] - offsets[traj]
        if not 0 <= step < length:
            raise ValueError(f"step {step} outside trajectory {traj} ({length} steps)")
        i = offsets[traj] + step
        img = frames["rgb"][i, c]
        if windows is not None:
            img = _crop(img, windows[c])
        masks = feats["masks"][i, c].astype(np.float32)
        axes[r, 0].imshow(img)
        axes[r, 0].set_ylabel(f"traj {traj} t={step}\n{cams[c]}", fontsize=6)
        extent = (-0.5, img.shape[1] - 0.5, img.shape[0] - 0.5, -0.5)
        axes[r, 1].imshow(palette[masks.argmax(0)], extent=extent)
        for k in range(K):
            axes[r, k + 2].imshow(img, alpha=0.35)
            axes[r, k + 2].imshow(masks[k], cmap="magma", vmin=0, vmax=1, alpha=0.75, extent=extent)
            if r == 0:
                axes[r, k + 2].set_title(f"slot {k}", fontsize=7, color=palette[k])
        if r == 0:
            axes[r, 1].set_title("argmax slot", fontsize=7)
    for ax in axes.flat:
        ax.set_xticks([]), ax.set_yticks([])
    fig.suptitle(f"{fa['task']} — {feats.attrs['encoder']} slot attention", fontsize=8)
    fig.tight_layout()
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
