"""Where a running (or finished) workflow run stands: `ocpipe progress`.

Read from what a run leaves behind, so it works from a second terminal while the run goes on: the newest run log
under `.snakemake/log/` (its plan, the jobs it started and finished), each running job's own log file (the last
line of its progress bar) and the benchmark files of the finished jobs (their CPU time).

The time left is an estimate, and says what it rests on: for each rule, the median CPU time of this run's
finished jobs of that rule, times the rule's jobs still to run, summed and divided by the cores. It assumes the
cores stay busy and that a rule's later jobs cost what its earlier ones did (a StackCube stability run costs more
than a PickCube one); jobs of rules with no finished job yet are counted apart, not guessed."""

from __future__ import annotations

import re
import statistics
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from .compute import benchmark_times

JOB_START = re.compile(r"^\[(?P<date>[^\]]+)\]\n(?:local)?rule (?P<rule>\w+):\n(?P<body>(?:[ \t]+.*\n?)*)",
                       re.MULTILINE)
FINISHED = re.compile(r"^Finished jobid: (?P<id>\d+) \(Rule: (?P<rule>\w+)\)", re.MULTILINE)
STEPS = re.compile(r"^(?P<done>\d+) of (?P<total>\d+) steps \(\d+%\) done", re.MULTILINE)
FIELD = re.compile(r"^\s+(?P<key>\w+): (?P<value>.*)$", re.MULTILINE)


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


def estimate(run: Run, workdir, cores: int) -> tuple[float, dict[str, int]]:
    """-> (seconds left if the cores stay busy, {rule: jobs left with no finished job to go by})."""
    history: dict[str, list[float]] = {}
    finished_by_rule: Counter = Counter()
    for job in (run.jobs[i] for i in run.finished if i in run.jobs):
        finished_by_rule[job.rule] += 1
        cpu = cpu_seconds(Path(workdir, job.benchmark)) if job.benchmark else None
        if cpu is not None:
            history.setdefault(job.rule, []).append(cpu)
    seconds, unknown = 0.0, {}
    for rule, count in run.planned.items():
        left = count - finished_by_rule.get(rule, 0)
        if left <= 0:
            continue
        if rule in history:
            seconds += statistics.median(history[rule]) * left
        else:
            unknown[rule] = left
    return seconds / max(cores, 1), unknown


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
    left, unknown = estimate(run, workdir, cores)
    n_left, n_unknown = run.total - run.done, sum(unknown.values())
    out.append(f"left: {n_left} jobs; {n_left - n_unknown} of them about {_minutes(left)} on {cores} cores (for each "
               "rule, the median CPU time of this run's finished jobs x its jobs left; cores kept busy)")
    if unknown:
        out.append(f"  the other {n_unknown}, of rules with no finished job yet, are not in that figure: "
                   + ", ".join(f"{rule} x{n}" for rule, n in sorted(unknown.items())))
    return out
