"""One screen of headline figures from the reports a run left under results/."""

from __future__ import annotations

import json
from pathlib import Path

from ..features import probes
from .findings import SCOPES


def _fmt(x, spec=".3f"):
    return "n/a" if x is None else format(x, spec)


def summary_lines(results: str | Path) -> list[str]:
    """What a build holds, one stage after another, then its tables (Table 5.1 and the findings first)."""
    results = Path(results)
    lines = _stores(results) + _encoder(results) + _features(results) + _policies(results)
    for path in _tables_in_order(results):
        lines += ["", path.read_text().rstrip()]
    return lines or [f"nothing built under {results} yet"]


def _stores(results: Path) -> list[str]:
    lines = []
    for path in sorted(results.glob("demos/*.report.json")):
        r = json.loads(path.read_text())
        lines.append(f"demos     {path.name.removesuffix('.report.json')}: {r['episodes']} episodes, seeds "
                     f"{r['seed_min']}..{r['seed_max']}, failed plans {r.get('failed_plans', 0)}")
    for path in sorted(results.glob("frames/*.report.json")):
        r = json.loads(path.read_text())
        offsets = ", ".join(f"{c} {_fmt(v, '.2f')} px" for c, v in r["goal2d_approx_offset_px_mean"].items())
        lines.append(
            f"frames    {path.name.removesuffix('.report.json')}: {r['frames']} frames / {r['episodes']} "
            f"episodes, replay success {r['replay_success_rate']:.3f}, "
            f"{_fmt(r.get('frames_per_second_per_job'), '.1f')} frames/s per job, approx-goal offset {offsets}"
        )
    return lines


def _encoder(results: Path) -> list[str]:
    ev = results / "encoders" / "slots_ssl" / "held_out_decomposition.json"
    if not ev.is_file():
        return []
    r = json.loads(ev.read_text())
    lines = [f"encoder   slots_ssl: trained {r['steps']} steps in {r['train_seconds'] / 60:.1f} min"]
    for store, s in r["held_out"].items():
        a = s["all"]
        named = ", ".join(f"{k.removeprefix('best_slot_iou_')} {_fmt(v)}" for k, v in a.items()
                          if k.startswith("best_slot_iou_") and not k.endswith("_images"))
        lines.append(f"          held-out {store} ({s['frames']} frames): FG-ARI {_fmt(a['fg_ari_mean'])}, "
                     f"best-slot IoU {named}")
    return lines


def _features(results: Path) -> list[str]:
    lines = []
    for path in sorted(results.glob("features/*.diagnostics.json")):
        r = json.loads(path.read_text())
        lines.append(
            f"features  {path.name.removesuffix('.diagnostics.json')}: tokens {r['tokens_shape']}, "
            f"{_fmt(r.get('encode_frames_per_second'), '.1f')} frames/s encoding"
        )
        if "probes" not in r:
            continue
        p = r["probes"]
        reads = "; ".join(
            f"{name.removesuffix('_pos')} "
            + ", ".join(f"{kind} {v['median_cm']:.1f}" for kind, v in p[name].items() if kind != "first_frames")
            for name in probes.TARGETS if name in p
        )
        lines.append(f"          position probes, median cm on {p['test_episodes']} held-out episodes: {reads}")
        first = p.get("obj_pos", {}).get("first_frames")
        if first:  # the object alone: the arm is not yet there to give it away
            reads = ", ".join(f"{kind} {v['median_cm']:.1f}" for kind, v in first.items())
            lines.append(f"          object on those episodes' first frames only: {reads}")
    return lines


def _policies(results: Path) -> list[str]:
    import polars as pl

    lines = []
    for path in sorted(results.glob("runs/*/train_log.parquet")):
        log = pl.read_parquet(path)
        best = path.parent / "best.json"
        picked = f", best checkpoint epoch {json.loads(best.read_text())['epoch']}" if best.is_file() else ""
        openloop = ""
        if "val_joint_err_rad" in log.columns:
            openloop = (f", open-loop joint error {log['val_joint_err_rad'][-1]:.4f} rad, gripper agreement "
                        f"{log['val_gripper_agree'][-1]:.3f} (held-out demos)")
        lines.append(
            f"policy    {path.parent.name}: {log['epoch'].max()} epochs, {log['seconds'].mean():.1f} s/epoch, "
            f"final loss {log['loss'][-1]:.4f}{openloop}{picked}"
        )
    return lines


def _tables_in_order(results: Path) -> list[Path]:
    """Table 5.1, then the findings (all twelve where built, else those of the targets built: main, ablations,
    StackCube), then the two-build comparisons of those built (target two_builds), then Tables 5.2-5.11."""
    tables = sorted(results.glob("tables/table5_*.md"), key=lambda p: int(p.stem.removeprefix("table5_")))
    every = results / "tables" / "findings.md"
    partial = [results / "tables" / f"{n}.md" for n in SCOPES if n != "findings"]  # main, ablations, StackCube
    findings = [every] if every.is_file() else [p for p in partial if p.is_file()]
    builds = [p for p in (results / "tables" / f"two_builds_{n}.md" for n in SCOPES if n != "findings") if p.is_file()]
    return tables[:1] + findings + builds + tables[1:]
