"""Slot diagnostics from the study (docs/study.md, Encoders) and decomposition quality against simulator
segmentation."""

from __future__ import annotations

import numpy as np


def mask_diagnostics(masks: np.ndarray) -> dict:
    """masks (M, K, h, w), summing to 1 over K. Thesis diagnostics, averaged over the M images."""
    M, K = masks.shape[:2]
    flat = masks.reshape(M, K, -1).astype(np.float64)
    activation = flat.mean(axis=2)  # (M, K)
    area = flat.sum(axis=2)  # (M, K)
    inter = np.einsum("mkp,mlp->mkl", flat, flat)
    denom = np.minimum(area[:, :, None], area[:, None, :])
    iu = np.triu_indices(K, 1)
    overlap = (inter / np.maximum(denom, 1e-9))[:, iu[0], iu[1]]
    coherence = 0.5 * (
        np.abs(np.diff(masks, axis=2)).mean(axis=(2, 3)) + np.abs(np.diff(masks, axis=3)).mean(axis=(2, 3))
    )
    p = np.clip(flat, 1e-9, 1.0)
    pixel_entropy = -(p * np.log(p)).sum(axis=1).mean(axis=1)  # (M,) entropy over slots, per pixel
    usage = area / area.sum(axis=1, keepdims=True)
    usage_entropy = -(np.clip(usage, 1e-9, 1) * np.log(np.clip(usage, 1e-9, 1))).sum(axis=1)
    return {
        "slot_activation_mean": activation.mean(axis=0).tolist(),
        "slot_overlap_mean": float(overlap.mean()),
        "spatial_coherence_mean_abs_diff": float(coherence.mean()),
        "slot_entropy_per_pixel_nats": float(pixel_entropy.mean()),
        "slot_usage_entropy_nats": float(usage_entropy.mean()),
        "max_entropy_nats": float(np.log(K)),
    }


def temporal_diversity(tokens: np.ndarray, episode_index: np.ndarray) -> float:
    """Mean over trajectories of the mean pairwise L2 distance between the trajectory's frame embeddings."""
    per_traj = []
    for e in np.unique(episode_index):
        emb = tokens[episode_index == e].reshape((episode_index == e).sum(), -1).astype(np.float64)
        if len(emb) < 2:
            continue
        sq = (emb**2).sum(1)
        d2 = np.maximum(sq[:, None] + sq[None, :] - 2 * emb @ emb.T, 0)
        n = len(emb)
        per_traj.append(np.sqrt(d2)[np.triu_indices(n, 1)].mean())
    return float(np.mean(per_traj)) if per_traj else float("nan")


def adjusted_rand_index(labels_true: np.ndarray, labels_pred: np.ndarray) -> float:
    """ARI of two flat labelings (Hubert & Arabie). 1 = identical partitions, ~0 = chance."""
    _, t = np.unique(labels_true, return_inverse=True)
    _, p = np.unique(labels_pred, return_inverse=True)
    table = np.zeros((t.max() + 1, p.max() + 1), dtype=np.int64)
    np.add.at(table, (t, p), 1)
    comb = lambda x: x * (x - 1) / 2.0  # noqa: E731
    sum_cells = comb(table).sum()
    sum_rows, sum_cols = comb(table.sum(1)).sum(), comb(table.sum(0)).sum()
    expected = sum_rows * sum_cols / max(comb(len(t)), 1)
    max_index = 0.5 * (sum_rows + sum_cols)
    if max_index == expected:
        return 1.0
    return float((sum_cells - expected) / (max_index - expected))


def decomposition_scores(
    masks: np.ndarray, object_ids: np.ndarray, foreground: np.ndarray, named: dict[str, np.ndarray]
) -> dict:
    """masks (M, K, h, w); object_ids (M, h, w) ground-truth object per cell (robot links merged into one id);
    foreground (M, h, w) bool; named: object name -> (M, h, w) bool mask.

    FG-ARI is computed per image over foreground cells with the argmax slot as the prediction; best-slot IoU of
    an object is, per image where it is visible, the highest IoU between its mask and any slot's argmax region.

    Separation: an object's *slot* in an image is the slot most of its cells are assigned to. ``own_slot_{name}`` is
    the fraction of images (where it is visible) in which that slot is neither the background's nor any other
    visible named object's; ``separate_{a}_{b}`` the fraction of images with both visible where their slots differ.
    These say whether objects are told apart even where a slot also takes part of the background (low IoU)."""
    pred = masks.argmax(axis=1)  # (M, h, w)
    aris = [
        adjusted_rand_index(object_ids[m][foreground[m]], pred[m][foreground[m]])
        for m in range(len(pred))
        if foreground[m].sum() > 1 and len(np.unique(object_ids[m][foreground[m]])) > 1
    ]
    out = {"fg_ari_mean": float(np.mean(aris)) if aris else None, "fg_ari_images": len(aris)}
    K = masks.shape[1]
    for name, obj in named.items():
        ious = []
        for m in range(len(pred)):
            if not obj[m].any():
                continue
            best = 0.0
            for k in range(K):
                region = pred[m] == k
                union = (region | obj[m]).sum()
                best = max(best, (region & obj[m]).sum() / union if union else 0.0)
            ious.append(best)
        out[f"best_slot_iou_{name}"] = float(np.mean(ious)) if ious else None
        out[f"best_slot_iou_{name}_images"] = len(ious)
    out.update(_separation(pred, ~foreground, named, K))
    return out


def _separation(pred: np.ndarray, background: np.ndarray, named: dict[str, np.ndarray], K: int) -> dict:
    def majority(m, region):
        return int(np.bincount(pred[m][region], minlength=K).argmax()) if region.any() else None

    names = list(named)
    slots = [
        {n: majority(m, named[n][m]) for n in names} | {"_bg": majority(m, background[m])} for m in range(len(pred))
    ]
    out = {}
    for n in names:
        own = [all(v is None or v != s[n] for k, v in s.items() if k != n) for s in slots if s[n] is not None]
        out[f"own_slot_{n}"] = float(np.mean(own)) if own else None
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            sep = [s[a] != s[b] for s in slots if s[a] is not None and s[b] is not None]
            out[f"separate_{a}_{b}"] = float(np.mean(sep)) if sep else None
    return out
