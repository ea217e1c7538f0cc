"""Where a running (or finished) workflow run stands: `ocpipe progress`.

Read from what a run leaves behind, so it works from a second terminal while the run goes on: the newest run log
under `.snakemake/log/` (its plan, the jobs it started and finished), each running job's own log file (the last
line of its progress bar) and the benchmark files of the finished jobs (their CPU time).

The time left is an estimate, and says what it rests on: for each rule, the median CPU time of this run's
finished jobs of that rule, times the rule's jobs still to run, summed and divided by the cores. It assumes the
cores stay busy and that a rule's later jobs cost what its earlier ones did (a StackCube stability run costs more
than a PickCube one). A rule with no finished job yet is priced from the recorded full run
(`docs/results/rule_times.csv`, which `ocpipe record` writes) where that run had it, and the estimate gives that
part apart, since another profile or machine costs otherwise; a rule in neither is counted, not guessed.

Why the text log and not a logger plugin: the log is what every run writes, whatever its executor and whoever
started it; a logger plugin writes only for runs started with `--logger`, so a run begun without it could not be
read, and `.snakemake/metadata` holds finished outputs only, not the plan or the running jobs. The patterns below
are tested on the log of a real run (tests/test_workflow.py, tests/test_cluster.py)."""

from __future__ import annotations

import re
import statistics
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import polars as pl

from ..util.atomic import atomic_path
from .compute import benchmark_times

JOB_START = re.compile(r"^\[(?P<date>[^\]]+)\]\n(?:local)?rule (?P<rule>\w+):\n(?P<body>(?:[ \t]+.*\n?)*)",
                       re.MULTILINE)
FINISHED = re.compile(r"^Finished jobid: (?P<id>\d+) \(Rule: (?P<rule>\w+)\)", re.MULTILINE)
STEPS = re.compile(r"^(?P<done>\d+) of (?P<total>\d+) steps \(\d+%\) done", re.MULTILINE)
FIELD = re.compile(r"^\s+(?P<key>\w+): (?P<value>.*)$", re.MULTILINE)
RULE_TIMES = Path("docs", "results", "rule_times.csv")  # a recorded run's per-rule CPU time, under the workdir


@dataclass
class Job:
    rule: str
    jobid: int
    started: datetime
    wildcards: str = ""
    log: str | None = None
    benchmark: str | None = None


@dataclass
class Run:
    log: Path
    started: datetime | None
    planned: dict[str, int]  # rule -> jobs in the plan
    jobs: dict[int, Job] = field(default_factory=dict)
    finished: set[int] = field(default_factory=set)
    done: int = 0
    total: int = 0


def newest_log(workdir) -> Path:
    logs = sorted(Path(workdir, ".snakemake", "log").glob("*.snakemake.log"))
    if not logs:
        raise FileNotFoundError(f"{Path(workdir, '.snakemake', 'log')}: no Snakemake run log (has a run started "
                                "in this folder?)")
    return logs[-1]


def provided_cores(log: Path) -> int:
    """The cores a run was given (its log's "Provided cores: N")."""
    found = re.search(r"^Provided cores: (\d+)$", log.read_text(errors="replace"), re.MULTILINE)
    if not found:
        raise ValueError(f"{log}: no 'Provided cores' line (pass --cores)")
    return int(found[1])


def _date(text: str) -> datetime | None:
    try:
        return datetime.strptime(text.strip(), "%a %b %d %H:%M:%S %Y")
    except ValueError:
        return None


def parse(log: Path) -> Run:
    text = log.read_text(errors="replace")
    planned = {}
    stats = re.search(r"^Job stats:\njob\s+count\n-+\s+-+\n(?P<rows>(?:\S+\s+\d+\n)+)", text, re.MULTILINE)
    if stats:
        for line in stats["rows"].splitlines():
            rule, count = line.split()
            if rule != "total":
                planned[rule] = int(count)
    run = Run(log, None, planned)
    for m in JOB_START.finditer(text):
        run.started = run.started or _date(m["date"])
        fields = {f["key"]: f["value"].strip() for f in FIELD.finditer(m["body"])}
        if "jobid" not in fields:
            continue
        job = Job(m["rule"], int(fields["jobid"]), _date(m["date"]), fields.get("wildcards", ""),
                  fields.get("log"), fields.get("benchmark"))
        run.jobs[job.jobid] = job
    run.finished = {int(m["id"]) for m in FINISHED.finditer(text)}
    steps = list(STEPS.finditer(text))
    if steps:
        run.done, run.total = int(steps[-1]["done"]), int(steps[-1]["total"])
    else:
        run.total = sum(planned.values())
    return run


def last_bar(log_file: Path) -> str:
    """The last line a job's log shows (a progress bar redraws itself with carriage returns)."""
    if not log_file.is_file():
        return ""
    tail = log_file.read_bytes()[-4000:].decode(errors="replace")
    lines = [s.strip() for s in re.split(r"[\r\n]", tail) if s.strip()]
    return lines[-1] if lines else ""


def cpu_seconds(benchmark: Path) -> float | None:
    """A finished job's CPU seconds; None where its benchmark file is missing or not yet whole."""
    try:
        return benchmark_times(benchmark)[1]
    except (OSError, IndexError, ValueError):
        return None


def cpu_history(run: Run, workdir) -> dict[str, list[float]]:
    """rule -> CPU seconds of each of the run's finished jobs whose benchmark file is whole."""
    history: dict[str, list[float]] = {}
    for job in (run.jobs[i] for i in sorted(run.finished) if i in run.jobs):
        cpu = cpu_seconds(Path(workdir, job.benchmark)) if job.benchmark else None
        if cpu is not None:
            history.setdefault(job.rule, []).append(cpu)
    return history


def write_rule_times(workdir, path) -> pl.DataFrame:
    """Every job of ``workdir``'s results with a benchmark file, whichever run made it, per rule: jobs, median and
    total CPU seconds, to ``path`` (CSV). The rule of a benchmark file is read from the run logs that started it."""
    rule_of = {}
    for log in sorted(Path(workdir, ".snakemake", "log").glob("*.snakemake.log")):
        rule_of |= {Path(workdir, j.benchmark).resolve(): j.rule for j in parse(log).jobs.values() if j.benchmark}
    history: dict[str, list[float]] = {}
    for bench, rule in rule_of.items():
        cpu = cpu_seconds(bench)
        if cpu is not None:
            history.setdefault(rule, []).append(cpu)
    if not history:
        raise FileNotFoundError(f"{workdir}: no run log names a job whose benchmark file is there to record")
    table = pl.DataFrame([{"rule": rule, "jobs": len(cpu), "median_cpu_seconds": round(statistics.median(cpu), 1),
                           "cpu_seconds": round(sum(cpu), 1)} for rule, cpu in sorted(history.items())])
    with atomic_path(path) as tmp:
        table.write_csv(tmp)
    return table


def read_rule_times(path) -> dict[str, float]:
    """A recorded run's rule -> median CPU seconds; empty where there is no record."""
    if not Path(path).is_file():
        return {}
    return dict(pl.read_csv(path).select("rule", "median_cpu_seconds").iter_rows())


@dataclass
class Estimate:
    """Seconds left on the given cores if they stay busy, priced from this run's finished jobs and, for rules
    with none yet, from a recorded run; jobs of rules in neither are counted by rule."""

    seconds: float = 0.0
    jobs: int = 0
    recorded_seconds: float = 0.0
    recorded_jobs: int = 0
    unknown: dict[str, int] = field(default_factory=dict)


def estimate(run: Run, workdir, cores: int, recorded: dict[str, float] | None = None) -> Estimate:
    history = cpu_history(run, workdir)
    finished_by_rule = Counter(run.jobs[i].rule for i in run.finished if i in run.jobs)
    recorded = recorded or {}
    est = Estimate()
    for rule, count in run.planned.items():
        left = count - finished_by_rule.get(rule, 0)
        if left <= 0:
            continue
        if rule in history:
            est.seconds += statistics.median(history[rule]) * left / max(cores, 1)
            est.jobs += left
        elif rule in recorded:
            est.recorded_seconds += recorded[rule] * left / max(cores, 1)
            est.recorded_jobs += left
        else:
            est.unknown[rule] = left
    return est


def _minutes(seconds: float) -> str:
    m = round(seconds / 60)
    return f"{m // 60} h {m % 60:02d} min" if m >= 60 else f"{m} min"


def lines(workdir=".", cores: int = 2, now: datetime | None = None) -> list[str]:
    run = parse(newest_log(workdir))
    now = now or datetime.now()
    out = [f"{run.log}: {run.done} of {run.total} jobs done"
           + (f" ({100 * run.done // run.total}%)" if run.total else "")
           + (f", started {_minutes((now - run.started).total_seconds())} ago" if run.started else "")]
    running = [j for i, j in sorted(run.jobs.items()) if i not in run.finished]
    out.append(f"running or interrupted: {len(running)}" if running else "running: none")
    for job in running:
        bar = last_bar(Path(workdir, job.log)) if job.log else ""
        what = f"{job.rule} {job.wildcards}".strip()
        out.append(f"  {what}" + (f"  |  {bar}" if bar else ""))
    est = estimate(run, workdir, cores, read_rule_times(Path(workdir, RULE_TIMES)))
    out.append(f"left: {run.total - run.done} jobs; {est.jobs} of them about {_minutes(est.seconds)} on {cores} "
               "cores (for each rule, the median CPU time of this run's finished jobs x its jobs left; cores kept "
               "busy)")
    if est.recorded_jobs:
        out.append(f"  {est.recorded_jobs} more, of rules with no finished job yet, about "
                   f"{_minutes(est.recorded_seconds)} as the recorded run ({RULE_TIMES}) priced their rules (its "
                   "profile and machine; another costs otherwise)")
    if est.unknown:
        out.append(f"  the other {sum(est.unknown.values())}, of rules with no finished job and no record, are not "
                   "in that figure: " + ", ".join(f"{rule} x{n}" for rule, n in sorted(est.unknown.items())))
    return out
