"""Where a run's time went, read from the rules' benchmark files (results/benchmarks/{rule}/{name}.tsv).

Every job is charged to what it built: an experiment (training, sweep, stability, the rest), a store (demos,
frames, features, scenes, an encoder's training) or a table (its own table, figure and findings jobs). Tables
then add up in config order: each is charged what it builds first, so the per-table totals sum to the run.
Core-minutes are the CPU time Snakemake measured for the job's process tree; job-minutes its wall time. The run's
wall time spans the first job's start (a file's modification time less its seconds) to the last job's end, and its
utilisation is core-minutes / (cores x wall time): the share of the cores the run kept busy (a results folder built
by several runs counts the pauses between them as idle). Beside it stands the rule "no job of two threads may wait
while a core idles", measured on the newest run log that names its cores (progress.idle_waits): the core-minutes left
idle while a job of more than one thread was ready and waiting, and the jobs that waited so; and that run's jobs'
CPU as the kernel counted it (run_cpu), which the benchmark files, sampling each job, undercount."""

from __future__ import annotations

import re
from pathlib import Path

import polars as pl

from ..config.experiments import features_store, frames_store, resolve
from ..study.findings import BY_ID, SCOPES
from ..study.registry import FIGURES, SPATIAL_FIGURES_JOB, SPATIAL_FIGURES_TABLE
from ..study.report import markdown
from ..study.tables import write_csv
from ..study.targets import experiments_of
from ..util.atomic import atomic_path
from . import run_cpu

# benchmark folder -> (what the job builds, stage); the file name, less a shard/epoch/run suffix, names the thing
EXPERIMENT_STAGES = {"train": "train", "sweep": "sweep", "stability": "stability", "best": "other",
                     "failures": "other", "failure_run": "other", "train_seed_run": "other",
                     "training_time_run": "stability",  # Table 5.5's run stands in for its rows' stability runs
                     "gallery": "gallery"}
STORE_STAGES = {"demos_shard": "demos", "demos_merge": "demos", "demos_import": "demos",
                "frames_shard": "frames", "frames_merge": "frames", "frames_report": "frames",
                "features": "features", "features_diagnostics": "features", "attention_maps": "features",
                "scenes_shard": "scenes", "scenes": "scenes"}
ENCODER_JOBS = {"train_slots_ssl": "slots_ssl", "train_spot_slots_on_dino": "spot"}
# a job's shard, epoch or run, and a policy's replicate (paths.policy_id): an experiment is charged for all its policies
SUFFIX = re.compile(r"(@\d+)?(_shard\d+|_epoch_\d+|_run_\d+)?$")
STAGES = ("train", "sweep", "stability", "other", "gallery", "demos", "frames", "features", "scenes", "encoder",
          "report")


def benchmark_times(path) -> tuple[float, float]:
    """A Snakemake benchmark file -> (wall seconds, CPU seconds) of its last repeat, read by the header's column
    names ``s`` and ``cpu_time``; ValueError where the file is not yet whole (a job still running)."""
    header, *repeats = Path(path).read_text().strip().splitlines()
    if not repeats:
        raise ValueError(f"{path}: a benchmark file without a measurement (is its job still running?)")
    last = dict(zip(header.split("\t"), repeats[-1].split("\t"), strict=True))
    return float(last["s"]), float(last["cpu_time"])


def read_jobs(bench_dir) -> pl.DataFrame:
    """One row per benchmark file: its folder (the rule), name, seconds, CPU seconds and end time (file mtime)."""
    rows = []
    for f in sorted(Path(bench_dir).rglob("*.tsv")):
        rel = f.relative_to(bench_dir)
        seconds, cpu = benchmark_times(f)
        folder = rel.parts[0] if len(rel.parts) > 1 else ""
        rows.append({"folder": folder, "name": rel.stem, "seconds": seconds, "cpu_seconds": cpu,
                     "end": f.stat().st_mtime})
    if not rows:
        raise FileNotFoundError(f"{bench_dir}: no benchmark files (has anything run here?)")
    return pl.DataFrame(rows)


def owner(folder: str, name: str) -> tuple[str, str, str]:
    """(kind, what, stage) a job is charged to; kind is experiment, store, encoder, table or lever."""
    base = SUFFIX.sub("", name)
    if folder in EXPERIMENT_STAGES:
        return "experiment", base, EXPERIMENT_STAGES[folder]
    if folder in STORE_STAGES:
        return "store", base, STORE_STAGES[folder]
    if not folder and name in ENCODER_JOBS:
        return "encoder", ENCODER_JOBS[name], "encoder"
    if folder in ("tables", "figures") or (not folder and name == "compute"):  # compute: this table's own job
        return "table", base, "report"
    if folder.startswith("lever") or name == "levers":
        return "lever", base, "lever"
    return "other", f"{folder}/{name}".strip("/"), "other"


def charged(jobs: pl.DataFrame) -> pl.DataFrame:
    """Jobs summed by what they built and stage: kind, what, stage, jobs, job_min, core_min."""
    owners = [owner(f, n) for f, n in zip(jobs["folder"], jobs["name"], strict=True)]
    return (jobs.with_columns(kind=pl.Series([o[0] for o in owners]), what=pl.Series([o[1] for o in owners]),
                              stage=pl.Series([o[2] for o in owners]))
            .group_by("kind", "what", "stage", maintain_order=True)
            .agg(jobs=pl.len(), job_min=(pl.col("seconds").sum() / 60).round(1),
                 core_min=(pl.col("cpu_seconds").sum() / 60).round(1))
            .sort("kind", "what", "stage"))


def builds_of(config: dict, exp: str) -> set[tuple[str, str]]:
    """(kind, what) an experiment needs built: itself, its stores, its task's demos and its encoder's training."""
    p = resolve(config, exp)
    out = {("experiment", exp), ("store", p["task"]), ("store", frames_store(p)), ("store", features_store(p)),
           ("encoder", p["encoder"])}
    if p["encoder"] == "slots_ssl":  # the encoder learns from its training stores' frames
        out |= {("store", s) for s in config["encoders"]["slots_ssl"]["train_stores"]}
        out |= {("store", s.split("_")[0]) for s in config["encoders"]["slots_ssl"]["train_stores"]}
    return out


def per_table(config: dict, totals: pl.DataFrame) -> pl.DataFrame:
    """Each table, in config order, with the core- and job-minutes of what it builds first."""
    cost = {(k, w): (j, c) for k, w, j, c in totals.select("kind", "what", "job_min", "core_min").iter_rows()}
    seen: set[tuple[str, str]] = set()
    rows = []
    for table in config["tables"]:
        wanted = {("table", table)} | {b for e in experiments_of(config, [table]) for b in builds_of(config, e)}
        if table == SPATIAL_FIGURES_TABLE:  # figures 5.1-5.3 come with the main job's table
            wanted |= {("table", SPATIAL_FIGURES_JOB)}
        # a target's findings (findings_main, _ablations, _stackcube) come with the first table they judge
        wanted |= {("table", scope) for scope, ids in SCOPES.items()
                   if scope != "findings" and ids and BY_ID[ids[0]].table == table}
        wanted |= {("table", f) for f, fig in FIGURES.items() if fig.table == table}
        new = wanted - seen
        seen |= new
        rows.append({"table": table, "job_min": round(sum(cost.get(b, (0, 0))[0] for b in new), 1),
                     "core_min": round(sum(cost.get(b, (0, 0))[1] for b in new), 1)})
    rest = set(cost) - seen
    rows.append({"table": "other (encodings, findings, levers)", "job_min": round(sum(cost[b][0] for b in rest), 1),
                 "core_min": round(sum(cost[b][1] for b in rest), 1)})
    return pl.DataFrame(rows)


def by_kind(by_stage: pl.DataFrame, kind: str) -> pl.DataFrame:
    """One row per experiment (store, encoder) of ``kind``: core-minutes per stage, in pipeline order, and total."""
    t = (by_stage.filter(pl.col("kind") == kind)
         .pivot(on="stage", index="what", values="core_min", aggregate_function="sum").fill_null(0.0))
    stages = [s for s in STAGES if s in t.columns]
    if not stages:  # nothing of this kind ran (a folder holding only demos, say)
        return pl.DataFrame(schema={"what": pl.String, "total": pl.Float64})
    return t.select("what", *stages).with_columns(total=pl.sum_horizontal(*stages).round(1))


def _minutes(table: pl.DataFrame) -> pl.DataFrame:
    """Minutes to one decimal as text (the Markdown writer would print 0.300)."""
    return table.with_columns(pl.col(pl.Float64).round(1).cast(pl.Utf8))


def wall_minutes(jobs: pl.DataFrame) -> float:
    start = (jobs["end"] - jobs["seconds"]).min()
    return round((jobs["end"].max() - start) / 60, 1)


def utilisation(jobs: pl.DataFrame, cores: int) -> float:
    """Core-minutes / (cores x wall minutes): the share of ``cores`` the run's jobs kept busy, 0-1."""
    return jobs["cpu_seconds"].sum() / 60 / (cores * wall_minutes(jobs))


def run_log_text(workdir) -> str:
    """The compute table's words on the newest run log in ``workdir`` that names its cores (where the
    utilisation's cores come from), on that run's own cores: how long jobs of 2+ threads waited while a core
    idled, and the run's jobs' CPU as the kernel counted it (run_cpu), which the benchmark files undercount."""
    from . import progress  # progress imports this module (benchmark_times): imported once both exist

    found = progress.cores_log(workdir)
    if found is None:
        return "jobs of 2+ threads waiting with a core idle: not known (no run log names its cores)"
    log, cores = found
    run = progress.parse(log)
    waits = progress.idle_waits(run, cores)
    who = "; ".join(f"{w.job}: {w.idle_core_seconds:.0f} core-s in a {w.waited_seconds:.0f} s wait" for w in waits.jobs)
    text = (f"jobs of 2+ threads waited with a core idle: {waits.core_seconds / 60:.1f} core-minutes "
            f"({len(waits.jobs)} of {waits.wide_jobs} such jobs{': ' + who if who else ''}; run log {log.name})")
    counted = run_cpu.read(log, workdir)
    if counted is None:
        return text + ("; that run's CPU by the kernel's count: none kept yet (a run keeps it when it ends: "
                       "ocpipe compute then gives it)")
    if run.started is None or run.last_at is None or run.last_at <= run.started:
        return text + "; that run's CPU by the kernel's count: no job ran"
    wall = (run.last_at - run.started).total_seconds() / 60
    jobs_min = counted["jobs_cpu_seconds"] / 60
    return text + (f"; that run's jobs by the kernel's count: {jobs_min:.1f} core-minutes over its {wall:.1f} min "
                   f"(first job's start to its log's last line), {100 * jobs_min / (cores * wall):.0f} % of "
                   f"{cores} cores (benchmark files miss up to 30 s of each job's end: {run_cpu.FOLDER})")


def write(config: dict, bench_dir, csv_path, md_path, cores: int | None, workdir=None) -> pl.DataFrame:
    """The compute table of the run whose benchmark files are under ``bench_dir``, run on ``cores`` cores (None:
    not known, as on a cluster; then no utilisation). ``workdir`` holds the run logs (.snakemake/log); by default
    the folder above the results folder, as ``bench_dir`` is ``results/benchmarks``."""
    jobs = read_jobs(bench_dir)
    by_stage = charged(jobs)
    totals = by_stage.group_by("kind", "what", maintain_order=True).agg(pl.col("job_min", "core_min").sum())
    tables = per_table(config, totals)
    write_csv(by_stage, csv_path)
    wall = wall_minutes(jobs)
    parts = [markdown(_minutes(by_kind(by_stage, "experiment")), "Experiments: core-minutes by stage"),
             markdown(_minutes(by_kind(by_stage, "store")), "Stores: core-minutes by stage"),
             markdown(_minutes(by_kind(by_stage, "encoder")), "Encoders trained by the workflow: core-minutes"),
             markdown(_minutes(tables), "Tables: what each adds, in config order (minutes)")]
    footer = (f"{len(jobs)} jobs, {jobs['cpu_seconds'].sum() / 60:.1f} core-minutes, "
              f"{jobs['seconds'].sum() / 60:.1f} job-minutes; wall time {wall} min (first job's start to last "
              f"job's end, from {bench_dir}'s files); "
              + (f"utilisation {100 * utilisation(jobs, cores):.0f} % of {cores} cores (core-minutes / (cores x "
                 "wall time))" if cores else "utilisation not known (the run log names no core count)")
              + f"; {run_log_text(workdir or Path(bench_dir).resolve().parent.parent)}"
              + f". Profile {config.get('profile', '?')}.")
    text = "\n".join(parts) + f"\n{footer}\n"
    with atomic_path(md_path) as tmp:
        tmp.write_text(text)
    return by_stage
