"""One experiment's gallery (rule `gallery_experiment`): its picked episodes (selection) drawn from their recorded
states (render), one video per episode and one contact sheet per failure class, and a table of what was picked.

Writes ``videos/{class}-{policy}-{seed}.mp4`` (``policy``: the replicate index k of policy ``exp@k``) with
``{class}-{policy}-{seed}.html`` beside it (the video inside a page of its own: what the Snakemake report shows),
``sheets/{class}.png`` (the class's first pick) and ``episodes.csv``."""

from __future__ import annotations

import logging
from pathlib import Path

import polars as pl
from tqdm import tqdm

from .. import paths
from ..util import video_page
from ..util.atomic import atomic_path
from . import overlay, render, selection, sheet, slots, video

log = logging.getLogger(__name__)

MASK_CAMERA = 0  # the contact sheets show the slot masks of the policy's first camera (the base camera)
# x264 qualities tried in turn until an episode's page fits the single-file report (video_page.PAGE_LIMIT): the
# first keeps the overlay's text sharp; a long StackCube failure at 256 px may need the next
CRF_STEPS = (20, 26, 32)


def run_files(episode_files: list[str]) -> dict[int, str]:
    """Run number -> the episodes file of that run, for the evaluation runs a policy's failures were classified on."""
    out = {}
    for f in episode_files:
        runs = pl.read_parquet(f, columns=["run"])["run"].unique().to_list()
        if len(runs) != 1:
            raise ValueError(f"{f}: holds runs {runs}, one evaluation run expected")
        out[int(runs[0])] = f
    return out


def _no_views_text(policy: dict) -> str:
    return "no camera: the policy reads the simulator's object pose" if policy["encoder"] == "state" else ""


def build_experiment(exp: str, policy: dict, config: dict, gallery: dict, near_miss_m: float, seed: int,
                     tables: dict[str, str], classes: dict[str, str], runs: dict[str, list[str]],
                     frames_store: str | None, encoder_checkpoint: str | None, videos_dir, sheets_dir, manifest,
                     progress: bool = True) -> pl.DataFrame:
    """``classes``: policy id -> its failures.parquet; ``runs``: policy id -> the episodes files those classes were
    read from. ``config``: what the experiment's evaluation env and encoder are built from (job_params
    .evaluation_job). ``tables``: table -> this experiment's row label there."""
    task = policy["task"]
    row = selection.row_title(tables)
    picks = selection.pick(selection.candidates({pid: pl.read_parquet(f) for pid, f in classes.items()}),
                           gallery["episodes_per_class"], seed, row=exp)
    log.info("%s: %d episodes of classes %s", row, len(picks), sorted(set(picks["class"].to_list())))
    records: dict[tuple[str, int, int], object] = {}
    steps_of: dict[tuple[str, int, int], pl.DataFrame] = {}
    for (pid, run), group in picks.group_by(["policy", "run"], maintain_order=True):
        files = run_files(runs[pid])
        if run not in files:
            raise ValueError(f"policy {pid}: its failures name run {run}, which none of {runs[pid]} holds")
        episodes = pl.read_parquet(files[run])
        steps = pl.read_parquet(paths.steps_beside(files[run]))
        wanted = set(group["seed"].to_list())
        for s, record in render.recorded_episodes(task, episodes, steps, wanted, files[run]).items():
            records[pid, run, s] = record
            steps_of[pid, run, s] = steps.filter(pl.col("seed") == s)
    views = render.Views(policy, config, gallery["resolution"], gallery["viewer_shader"])
    encoder = slots.slot_encoder(policy, config["encoders"], frames_store, encoder_checkpoint, MASK_CAMERA) \
        if frames_store else None
    rows = []
    try:
        with atomic_path(videos_dir) as videos_tmp, atomic_path(sheets_dir) as sheets_tmp:
            videos_tmp.mkdir()
            sheets_tmp.mkdir()
            for pick in tqdm(picks.iter_rows(named=True), total=len(picks), desc=f"gallery {exp}", unit="episode",
                             disable=not progress):
                key = (pick["policy"], pick["run"], pick["seed"])
                rows.append(_episode(pick, records[key], steps_of[key], views, encoder, row, policy, gallery,
                                     near_miss_m, Path(videos_tmp), Path(sheets_tmp)))
    finally:
        views.close()
    table = pl.DataFrame(rows, schema_overrides={"deciding_step": pl.Int64, "deciding_distance_m": pl.Float64})
    with atomic_path(manifest) as tmp:
        table.write_csv(tmp)
    return table


def _episode(pick: dict, record, steps: pl.DataFrame, views: render.Views, encoder, row: str, policy: dict,
             gallery: dict, near_miss_m: float, videos_dir: Path, sheets_dir: Path) -> dict:
    """One picked episode's video (and its class's contact sheet, for the class's first pick) -> its manifest row."""
    failure_class, pid, seed = pick["class"], pick["policy"], pick["seed"]
    facts = overlay.episode_facts(steps, failure_class)
    n = facts.steps
    with_sheet = pick["n"] == 0
    sheet_steps = sheet.sheet_steps(n, gallery["sheet_frames"], facts.deciding_step) if with_sheet else []
    drawn = render.drawn_frames(n, gallery["frame_stride"], sheet_steps)
    frames, panels = [], {}
    for k, viewer, views_seen in views.frames(record, drawn):
        lines = overlay.frame_lines(row, failure_class, pid, seed, k, facts, near_miss_m)
        frame = overlay.compose(viewer, views_seen, lines, _no_views_text(policy))
        if k % gallery["frame_stride"] == 0 or k == n:
            frames.append(frame)
        if k in sheet_steps:
            panels[k] = (viewer, views_seen)
    name = f"{selection.slug(failure_class)}-{paths.split_policy(pid)[1]}-{seed}"
    deciding = overlay.deciding_line(facts, failure_class, near_miss_m)
    page_lines = (f"policy {pid}, seed {seed}: {n} steps, {'success' if record.success else 'no success'}",
                  deciding)
    written = write_video_and_page(frames, videos_dir / f"{name}.mp4", gallery["fps"],
                                   f"{row}: {failure_class}", tuple(line for line in page_lines if line))
    sheet_name = ""
    if with_sheet:
        sheet_name = f"{selection.slug(failure_class)}.png"
        episode = " | ".join(part for part in (failure_class, f"policy {pid}", f"seed {seed}", f"{n} steps", deciding)
                             if part)
        _write_sheet(sheets_dir / sheet_name, panels, sheet_steps, views, encoder, row, episode,
                     gallery["resolution"] // 2)
    return {"row": row, "class": failure_class, "policy": pid, "run": pick["run"], "seed": seed, "steps": n,
            "success": record.success, "video": written.name, "sheet": sheet_name,
            "deciding_step": facts.deciding_step, "deciding_distance_m": facts.deciding_distance}


def write_video_and_page(frames: list, path: Path, fps: float, title: str, lines: tuple[str, ...]) -> Path:
    """The episode's video at ``path`` (or its GIF) and its report page beside it (.html), at the first of CRF_STEPS
    whose page the single-file report can show. Returns the video written."""
    for crf in CRF_STEPS:
        written = video.write_video(frames, path, fps, crf=crf)
        try:
            video_page.write(written, path.with_suffix(".html"), title, lines)
            return written
        except ValueError as err:
            if crf == CRF_STEPS[-1] or written.suffix != ".mp4":
                raise
            log.info("%s; encoding again at crf %d", err, CRF_STEPS[CRF_STEPS.index(crf) + 1])
    raise AssertionError("unreachable")


def _write_sheet(path: Path, panels: dict, steps: list[int], views: render.Views, encoder, row: str, episode: str,
                 cell: int) -> None:
    names = ["viewer (original robot)"] + [f"policy view: {c}" for c in views.camera_names]
    grid = [[panels[k][0] for k in steps]] + [[panels[k][1][i] for k in steps] for i in range(len(views.camera_names))]
    if encoder is not None:
        names.append(f"slot masks: {views.camera_names[MASK_CAMERA]}")
        grid.append([slots.slot_map(encoder, panels[k][1][MASK_CAMERA]) for k in steps])
    image = sheet.contact_sheet([row, episode], names, steps, grid, cell)
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")


def frames_in_video(steps: int, stride: int) -> int:
    """How many frames the video of an episode of ``steps`` actions holds: every ``stride``-th state from the reset,
    and the last."""
    return len(render.drawn_frames(steps, stride))

