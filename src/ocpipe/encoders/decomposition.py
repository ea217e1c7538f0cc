"""Scoring slot masks against the simulator's own per-actor segmentation (stored with every frames store)."""

from __future__ import annotations

import numpy as np

from . import crop, slot_metrics

ROBOT_PREFIX = "panda"
BACKGROUND = {"ground", "table-workspace"}
# the objects whose best-slot IoU is reported, by task: name in the report -> actor name in the simulator
NAMED_OBJECTS = {
    "PickCube-v1": {"cube": "cube", "goal_marker": "goal_site"},
    "StackCube-v1": {"cubeA": "cubeA", "cubeB": "cubeB"},
}


def ground_truth(seg: np.ndarray, segmentation_ids: dict[str, str], task: str):
    """seg (..., h, w) actor ids -> (object ids with all robot links merged, foreground mask, named masks)."""
    ids = {name: int(i) for i, name in segmentation_ids.items()}
    robot_ids = [i for name, i in ids.items() if name.startswith(ROBOT_PREFIX)]
    robot = np.isin(seg, robot_ids)
    objects = np.where(robot, -1, seg.astype(np.int64))
    background = np.isin(seg, [ids[n] for n in BACKGROUND if n in ids]) | (seg == 0)
    named = {report: seg == ids[actor] for report, actor in NAMED_OBJECTS[task].items() if actor in ids}
    named["robot"] = robot
    return objects, ~background, named


def score_masks(masks: np.ndarray, seg: np.ndarray, windows: np.ndarray | None, segmentation_ids: dict, task: str,
                cameras: list[str]) -> dict:
    """masks (M, C, K, g, g) for frames whose segmentation is seg (M, C, H, W); per camera and overall."""
    g = masks.shape[-1]
    if windows is None:  # masks cover the whole image
        windows = np.array([(0, 0, seg.shape[-1])] * seg.shape[1])
    labels = crop.crop_labels(seg, windows, g)  # (M, C, g, g)
    out = {}
    for c, cam in enumerate(cameras + ["all"]):
        sel = slice(None) if cam == "all" else slice(c, c + 1)
        m = masks[:, sel].reshape(-1, *masks.shape[2:]).astype(np.float32)
        objects, fg, named = ground_truth(labels[:, sel].reshape(-1, g, g), segmentation_ids, task)
        out[cam] = slot_metrics.decomposition_scores(m, objects, fg, named)
    return out
