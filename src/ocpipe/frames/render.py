"""The frames stage: replay a block of demos, render, and write a shard store; fail loudly on a bad replay."""

from __future__ import annotations

import time
from pathlib import Path

from tqdm import tqdm

from ..demos.files import check_pair, open_h5
from ..util.atomic import atomic_path
from .replay import Replayer, select_episodes
from .store import StoreWriter


class ReplayFailure(RuntimeError):
    pass


def render_shard(task: str, camera_set: str, resolution: int, demo_h5: str | Path, shard: int, n_shards: int,
                 config: dict, out_path: str | Path, progress: bool = True) -> dict:
    demo_h5 = Path(demo_h5)
    check_pair(demo_h5)  # a damaged or mismatched demo set fails here, before a simulator is built
    eps = select_episodes(demo_h5.with_suffix(".json"), shard, n_shards)
    if not eps:
        raise ValueError(f"frames shard {shard}/{n_shards} of {demo_h5} has no episodes; lower frames.shards")
    replayer = Replayer(task, config, camera_set, resolution)
    failed, state_err, offsets = [], 0.0, [0]
    t0 = time.perf_counter()
    with atomic_path(out_path) as tmp, open_h5(demo_h5) as h5:
        writer = StoreWriter(tmp, replayer.cameras, resolution, config["frames"]["chunk_frames"],
                             moving_cameras="hand" in replayer.cameras)
        bar = tqdm(eps, desc=f"{task} {camera_set} {resolution}px shard {shard}", unit="ep", disable=not progress)
        for i, ep in enumerate(bar):
            result = replayer.replay(h5, ep)
            if not result.success:
                failed.append(result.episode_id)
            state_err = max(state_err, result.max_state_error)
            writer.add(result.arrays, i)
            offsets.append(offsets[-1] + len(result.arrays["action"]))
            bar.set_postfix(frames=offsets[-1], failed=len(failed))
        replayer.close()
        if failed:
            # raising inside atomic_path discards the temporary store: no artifact is left behind
            raise ReplayFailure(f"{task}: env-state replay failed for episode ids {failed} of {demo_h5}")
        seconds = time.perf_counter() - t0
        writer.close({
            "task": task, "camera_set": camera_set, "cameras": replayer.cameras, "resolution": resolution,
            "episode_seeds": [int(e["episode_seed"]) for e in eps], "episode_ids": [int(e["episode_id"]) for e in eps],
            "episode_offsets": offsets, "replay_success_rate": 1.0, "goal_marker_visible":
            config["frames"]["goal_marker_visible"], "shader": config["sim"]["shader"],
            "max_replay_state_error": state_err,
            "segmentation_ids": {str(k): v for k, v in replayer.segmentation_ids.items()}, "render_seconds": seconds,
        })
    return {"frames": offsets[-1], "episodes": len(eps), "seconds": seconds, "frames_per_s": offsets[-1] / seconds}
