"""Summary JSON and a contact sheet (frames with the projected goal drawn) for a frames store."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..util.atomic import atomic_path, write_json
from .store import open_store


def summarize(store_path: str | Path, render_seconds: list[float] | None = None) -> dict:
    root = open_store(store_path)
    a = root.attrs.asdict()
    R = a["resolution"]
    exact, approx = root["goal2d_exact"][...], root["goal2d_approx"][...]
    offset = np.linalg.norm((approx - exact).reshape(len(exact), -1, 2) * R, axis=-1)  # (N, C) pixels
    summary = {
        "store": str(store_path), "task": a["task"], "cameras": a["cameras"], "resolution": R,
        "frames": int(root["action"].shape[0]), "episodes": len(a["episode_seeds"]),
        "mean_frames_per_episode": float(np.mean(np.diff(a["episode_offsets"]))),
        "replay_success_rate": a["replay_success_rate"],
        "goal2d_approx_offset_px_mean": {c: float(np.nanmean(offset[:, i])) if np.isfinite(offset[:, i]).any()
                                         else None for i, c in enumerate(a["cameras"])},
        "goal2d_approx_offset_px_max": {c: float(np.nanmax(offset[:, i])) if np.isfinite(offset[:, i]).any()
                                        else None for i, c in enumerate(a["cameras"])},
        "grasped_fraction": float(root["is_grasped"][...].mean()),
    }
    if render_seconds:
        summary["render_seconds_total"] = float(sum(render_seconds))
        summary["frames_per_second_per_job"] = summary["frames"] / float(sum(render_seconds))
    return summary


def contact_sheet(store_path: str | Path, out_png: str | Path, n_episodes: int, n_steps: int) -> None:
    """Grid: rows = (episode, camera), columns = evenly spaced steps; exact goal as a circle, approx as a cross."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    root = open_store(store_path)
    a = root.attrs.asdict()
    R, cams, offsets = a["resolution"], a["cameras"], a["episode_offsets"]
    n_ep = len(offsets) - 1
    episodes = np.unique(np.linspace(0, n_ep - 1, min(n_episodes, n_ep)).round().astype(int))
    fig, axes = plt.subplots(
        len(episodes) * len(cams), n_steps, figsize=(1.8 * n_steps, 1.8 * len(episodes) * len(cams)), squeeze=False
    )
    for ei, e in enumerate(episodes):
        steps = np.linspace(offsets[e], offsets[e + 1] - 1, n_steps).round().astype(int)
        for si, frame in enumerate(steps):
            rgb = root["rgb"][int(frame)]
            gx, ga = root["goal2d_exact"][int(frame)] * R, root["goal2d_approx"][int(frame)] * R
            for ci, cam in enumerate(cams):
                ax = axes[ei * len(cams) + ci, si]
                ax.imshow(rgb[ci], interpolation="nearest")
                ax.scatter([gx[2 * ci]], [gx[2 * ci + 1]], s=60, facecolors="none", edgecolors="yellow", linewidths=1.2)
                if np.isfinite(ga[2 * ci]):
                    ax.scatter([ga[2 * ci]], [ga[2 * ci + 1]], s=30, marker="x", c="cyan", linewidths=1)
                ax.set_xticks([]), ax.set_yticks([])
                ax.set_title(f"ep {e} seed {a['episode_seeds'][e]} t={frame - offsets[e]}\n{cam}", fontsize=6)
    fig.suptitle(f"{a['task']} {R}px — goal: exact (yellow circle), approx (cyan x)", fontsize=8)
    fig.tight_layout()
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def write_report(store_path, out_json, out_png, n_episodes, n_steps, render_seconds=None) -> dict:
    summary = summarize(store_path, render_seconds)
    contact_sheet(store_path, out_png, n_episodes, n_steps)
    write_json(out_json, summary)
    return summary
