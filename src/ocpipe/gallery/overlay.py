"""What a gallery frame says about itself, and the frame put together: the viewer camera, beside it the views the
policy saw, and below both a caption with the row, the failure class, the episode, the step, the gripper (commanded
and grasped) and the fact that decided the class (Near Miss: the closest the TCP came to the goal; Drop: how far
the object was from the goal when the grasp was lost).

Frame k shows the env after k actions (k = 0: the reset). The episode's record labels observation k (the state
before action k) for k < n, so frame k's grasp flag and distances are the record's step k; the last frame, after
the last action, was never observed by the evaluation and says so."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from ..evaluation import taxonomy

CAPTION_LINES = 5  # every frame of a video has the same size: the caption is this many lines, wrapped to fit
FONT_SIZE = 11
LINE_HEIGHT = 14
MARGIN = 4
# blank rows under the caption: a browser draws a paused video's controls (~60 px tall) over its bottom, which would
# hide the caption just when a reader stops to read it
CONTROLS_BAND = 64
BACKGROUND = (24, 24, 24)
TEXT = (235, 235, 235)
PANEL = (60, 60, 60)


@dataclass(frozen=True)
class EpisodeFacts:
    """What one episode's record says, for its caption: per observed step the grasp flag and the distances, and the
    step and distance that decided its class (None where its class has none)."""

    steps: int
    grasped: np.ndarray  # (n,) bool: observation t grasped the object
    tcp_goal: np.ndarray  # (n,) m
    obj_goal: np.ndarray  # (n,) m
    gripper: np.ndarray  # (n,) the commanded gripper of action t: +1 open, -1 closed
    deciding_step: int | None = None
    deciding_distance: float | None = None


def _positions(steps: pl.DataFrame, col: str) -> np.ndarray:
    return np.asarray(steps[col].to_list(), dtype=np.float64)


def episode_facts(steps: pl.DataFrame, failure_class: str) -> EpisodeFacts:
    """``steps``: one episode's rows of a steps file. Near Miss: the step of the smallest TCP-goal distance (the
    taxonomy's, which it compares with near_miss_m); Drop: the first step after the last grasped one, and the
    object-goal distance there."""
    steps = steps.sort("step")
    grasped = np.asarray(steps["is_grasped"].to_list(), dtype=bool)
    tcp_goal = taxonomy.tcp_goal_distance(steps)
    obj_goal = taxonomy.obj_goal_distance(steps)
    gripper = _positions(steps, "action")[:, 7]
    step = None
    if failure_class == "Near Miss":
        step = int(np.argmin(tcp_goal))
        distance = float(tcp_goal[step])
    elif failure_class == "Drop":
        held = np.flatnonzero(grasped)
        if not len(held) or held[-1] == len(grasped) - 1:
            raise ValueError(f"episode seed {steps['seed'][0]}: classed Drop but its record never lets go of a grasp")
        step = int(held[-1]) + 1
        distance = float(obj_goal[step])
    return EpisodeFacts(len(steps), grasped, tcp_goal, obj_goal, gripper, step,
                        None if step is None else distance)


def deciding_line(facts: EpisodeFacts, failure_class: str, near_miss_m: float) -> str:
    if failure_class == "Near Miss":
        return (f"closest TCP-goal {facts.deciding_distance:.3f} m at step {facts.deciding_step} "
                f"(Near Miss: < {near_miss_m:g} m)")
    if failure_class == "Drop":
        return f"grasp lost at step {facts.deciding_step}: object {facts.deciding_distance:.3f} m from the goal"
    if failure_class == "Success":
        return f"success after {facts.steps} steps"
    return ""


def frame_lines(row: str, failure_class: str, policy: str, seed: int, k: int, facts: EpisodeFacts,
                near_miss_m: float) -> list[str]:
    """The caption of frame ``k`` (the env after k actions) of an episode: the fact that decided the class comes
    right after the class, so a caption cut to CAPTION_LINES never loses it."""
    n = facts.steps
    if not 0 <= k <= n:
        raise ValueError(f"frame {k} of an episode of {n} steps")
    command = "-" if k == 0 else ("open" if facts.gripper[k - 1] >= 0 else "closed")
    if k < n:
        grasped = "yes" if facts.grasped[k] else "no"
        where = f"TCP-goal {facts.tcp_goal[k]:.3f} m, object-goal {facts.obj_goal[k]:.3f} m"
    else:  # after the last action: the evaluation observed no more
        grasped, where = "not observed", "after the last action: not observed by the evaluation"
    deciding = deciding_line(facts, failure_class, near_miss_m)
    return [row, f"{failure_class} | policy {policy} | seed {seed}", *([deciding] if deciding else []),
            f"step {k}/{n} | gripper commanded {command} | grasped {grasped}", where]


def _font():
    from PIL import ImageFont

    return ImageFont.load_default(size=FONT_SIZE)


def wrap(lines: list[str], width_px: int, font=None) -> list[str]:
    """Lines wrapped at spaces to ``width_px`` (a word wider than that stands alone), then cut to CAPTION_LINES
    with the last kept line ending in '...'."""
    from PIL import Image, ImageDraw

    font = font or _font()
    draw = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    out = []
    for line in lines:
        current = ""
        for word in line.split(" "):
            longer = f"{current} {word}" if current else word
            if current and draw.textlength(longer, font=font) > width_px:
                out.append(current)
                current = word
            else:
                current = longer
        out.append(current)
    if len(out) > CAPTION_LINES:
        out = out[:CAPTION_LINES]
        out[-1] += " ..."
    return out


def compose(viewer: np.ndarray, views: list[np.ndarray], lines: list[str], no_views: str = "") -> np.ndarray:
    """One gallery frame (H, W, 3) uint8: ``viewer`` (S, S, 3) on the left; on the right a column S / 2 wide of the
    policy's ``views``, each scaled (nearest neighbour: its pixels as the policy got them) to fill its share of the
    height, or a panel saying ``no_views``; below both the caption, then CONTROLS_BAND blank rows. Both sides even,
    as H.264 in yuv420p needs."""
    from PIL import Image, ImageDraw

    size = viewer.shape[0]
    side = size // 2
    caption_h = CAPTION_LINES * LINE_HEIGHT + 2 * MARGIN
    width, height = size + side, size + caption_h + CONTROLS_BAND
    width, height = width + width % 2, height + height % 2
    canvas = Image.new("RGB", (width, height), BACKGROUND)
    canvas.paste(Image.fromarray(np.ascontiguousarray(viewer)), (0, 0))
    draw = ImageDraw.Draw(canvas)
    font = _font()
    if views:
        cell = min(side, size // len(views))
        for i, view in enumerate(views):
            scaled = Image.fromarray(np.ascontiguousarray(view)).resize((cell, cell), Image.Resampling.NEAREST)
            canvas.paste(scaled, (size, i * cell))
    else:
        draw.rectangle((size, 0, width - 1, size - 1), fill=PANEL)
        for i, line in enumerate(wrap([no_views], side - 2 * MARGIN, font)):
            draw.text((size + MARGIN, MARGIN + i * LINE_HEIGHT), line, fill=TEXT, font=font)
    for i, line in enumerate(wrap(lines, width - 2 * MARGIN, font)):
        draw.text((MARGIN, size + MARGIN + i * LINE_HEIGHT), line, fill=TEXT, font=font)
    return np.asarray(canvas)
