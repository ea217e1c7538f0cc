"""Where a running (or finished) workflow run stands: `ocpipe progress`.

Read from what a run leaves behind, so it works from a second terminal while the run goes on: the newest run log
under `.snakemake/log/` (its plan, the jobs it started and finished), each running job's own log file (the last
line of its progress bar) and the benchmark files of the finished jobs (their CPU time).

The time left is an estimate, and says what it rests on. A job is priced by what its cost scales with: its
rule and its kind, the rule's wildcards less the replicate, shard, run and checkpoint, which cost alike (a kind
names the experiment, so its task, window and epochs, and the rule fixes its episodes). A job whose kind has
finished jobs in this run costs their median CPU time; one whose kind has none yet (the first StackCube
training) costs what the recorded full run (`docs/results/rule_times.csv`, which `ocpipe record` writes) spent
on that kind, scaled by how fast this run's kinds have gone against the record's, else its rule's median in this
run; the sum is divided by the cores, as if they stay busy. Which jobs are still to come is read from a dry run
of the run's own command (`--nolock -n`); where that fails, only each rule's count is known, and every such job
costs its rule's median. A rule with no finished job yet is priced from the record's jobs of that rule, and the
estimate gives that part apart, since another profile or machine costs otherwise; a rule in neither is counted,
not guessed. `ocpipe progress --replay` checks the pricing on a finished run's log: at a quarter, half and three
quarters of its jobs, the estimate from the jobs finished by then against the time the run really took.

Why the text log and not a logger plugin: the log is what every run writes, whatever its executor and whoever
started it; a logger plugin writes only for runs started with `--logger`, so a run begun without it could not be
read, and `.snakemake/metadata` holds finished outputs only, not the plan or the running jobs. The patterns below
are tested on the log of a real run (tests/test_workflow.py, tests/test_cluster.py)."""

from __future__ import annotations

import re
import shlex
import statistics
import subprocess
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import polars as pl

from ..util.atomic import atomic_path
from .compute import benchmark_times

JOB_START = re.compile(r"^\[(?P<date>[^\]]+)\]\n(?:local)?rule (?P<rule>\w+):\n(?P<body>(?:[ \t]+.*\n?)*)",
                       re.MULTILINE)
FINISHED = re.compile(r"^(?:\[(?P<date>[^\]]+)\]\n)?Finished jobid: (?P<id>\d+) \(Rule: (?P<rule>\w+)\)",
                      re.MULTILINE)
STEPS = re.compile(r"^(?P<done>\d+) of (?P<total>\d+) steps \(\d+%\) done", re.MULTILINE)
FIELD = re.compile(r"^\s+(?P<key>\w+): (?P<value>.*)$", re.MULTILINE)
STAMP = re.compile(r"^\[(?P<date>[^\]]+)\]$", re.MULTILINE)  # a line of its own: each event's time
RULE_TIMES = Path("docs", "results", "rule_times.csv")  # a recorded run's per-rule CPU time, under the workdir
# wildcards that tell apart jobs of one cost: a policy's replicate (@k), a store's shard, a stability run, a swept
# checkpoint
ALIKE = re.compile(r"@\d+|,? ?\b(?:shard|run|epoch)=[^,]*")


@dataclass
class Job:
    rule: str
    jobid: int
    started: datetime | None
    wildcards: str = ""
    log: str | None = None
    benchmark: str | None = None
    threads: int = 1  # the log's `threads:` line, which Snakemake leaves out for a job of one thread
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()

    @property
    def kind(self) -> str:
        """The rule and what the job's cost scales with (its wildcards less replicate, shard, run, checkpoint)."""
        return f"{self.rule} {ALIKE.sub('', self.wildcards).strip(', ')}".strip()


@dataclass
class Run:
    log: Path | None
    started: datetime | None
    planned: dict[str, int]  # rule -> jobs in the plan
    jobs: dict[int, Job] = field(default_factory=dict)
    finished: set[int] = field(default_factory=set)
    finished_at: dict[int, datetime] = field(default_factory=dict)
    command: str | None = None  # the command line that started the run
    done: int = 0
    total: int = 0
    last_at: datetime | None = None  # the log's last timestamp: as far as it vouches for the run


def _paths(value: str | None) -> tuple[str, ...]:
    """A log's ``input:`` or ``output:`` value -> its paths (Snakemake joins them with ", ")."""
    return tuple(p.strip() for p in value.split(",") if p.strip()) if value else ()


def newest_log(workdir) -> Path:
    logs = sorted(Path(workdir, ".snakemake", "log").glob("*.snakemake.log"))
    if not logs:
        raise FileNotFoundError(f"{Path(workdir, '.snakemake', 'log')}: no Snakemake run log (has a run started "
                                "in this folder?)")
    return logs[-1]


def provided_cores(log: Path) -> int:
    """The cores a run was given (its log's "Provided cores: N")."""
    found = re.search(r"^Provided cores: (\d+)\b", log.read_text(errors="replace"), re.MULTILINE)
    if not found:
        raise ValueError(f"{log}: no 'Provided cores' line (pass --cores)")
    return int(found[1])


def cores_log(workdir) -> tuple[Path, int] | None:
    """The newest run log in ``workdir`` that names its cores (a dry run or a `--report` call writes a log
    without), and those cores; None where no log names any (a run on a cluster executor gives no core count)."""
    for log in sorted(Path(workdir, ".snakemake", "log").glob("*.snakemake.log"), reverse=True):
        try:
            return log, provided_cores(log)
        except ValueError:
            continue
    return None


def run_cores(workdir) -> int | None:
    """The cores the newest run in ``workdir`` that names them was given (cores_log); None where no log names any
    (Snakemake's own `workflow.cores` raises on a cluster executor, so the log is what tells)."""
    found = cores_log(workdir)
    return None if found is None else found[1]


def _date(text: str) -> datetime | None:
    try:
        return datetime.strptime(text.strip(), "%a %b %d %H:%M:%S %Y")
    except ValueError:
        return None


def parse(log: Path) -> Run:
    return parse_text(log.read_text(errors="replace"), log)


def parse_text(text: str, log: Path | None = None) -> Run:
    """A run log's (or a dry run's) text -> its plan, jobs and progress."""
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
                  fields.get("log"), fields.get("benchmark"), int(fields.get("threads", 1)),
                  _paths(fields.get("input")), _paths(fields.get("output")))
        run.jobs[job.jobid] = job
    for m in FINISHED.finditer(text):
        run.finished.add(int(m["id"]))
        if m["date"] and _date(m["date"]):
            run.finished_at[int(m["id"])] = _date(m["date"])
    stamps = [d for d in (_date(m["date"]) for m in STAMP.finditer(text)) if d]
    run.last_at = max(stamps, default=None)
    command = re.search(r"^\s*Command: (?P<cmd>.+)$", text, re.MULTILINE)
    run.command = command["cmd"].strip() if command else None
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


def job_times(benchmark: Path) -> tuple[float, float] | None:
    """A finished job's (wall, CPU) seconds; None where its benchmark file is missing or not yet whole."""
    try:
        return benchmark_times(benchmark)
    except (OSError, IndexError, ValueError):
        return None


def cpu_seconds(benchmark: Path) -> float | None:
    """A finished job's CPU seconds; None where its benchmark file is missing or not yet whole."""
    times = job_times(benchmark)
    return None if times is None else times[1]


def finished_times(run: Run, workdir) -> dict[int, tuple[float, float]]:
    """jobid -> (wall, CPU) seconds of each of the run's finished jobs whose benchmark file is whole."""
    out = {}
    for i in sorted(run.finished):
        job = run.jobs.get(i)
        times = job_times(Path(workdir, job.benchmark)) if job and job.benchmark else None
        if times is not None:
            out[i] = times
    return out


def cpu_of(times: dict[int, tuple[float, float]]) -> dict[int, float]:
    """jobid -> CPU seconds, of finished_times' (wall, CPU) pairs."""
    return {i: cpu for i, (_, cpu) in times.items()}


def utilisation_so_far(run: Run, times: dict[int, tuple[float, float]], now: datetime, cores: int) -> float | None:
    """The share of the cores the run has kept busy up to ``now``: the CPU seconds of the jobs finished by then,
    plus each job still running's wall time so far x the finished jobs' median CPU / wall, over cores x the time
    since the first job started. None before any job has finished."""
    ratios = [cpu / wall for wall, cpu in times.values() if wall > 0]
    starts = [j.started for j in run.jobs.values() if j.started]
    if not ratios or not starts or now <= min(starts):
        return None
    running = [j for i, j in run.jobs.items() if i not in times and j.started and j.started < now]
    used = sum(cpu for _, cpu in times.values())
    used += statistics.median(ratios) * sum((now - j.started).total_seconds() for j in running)
    return min(1.0, used / (max(cores, 1) * (now - min(starts)).total_seconds()))


@dataclass(frozen=True)
class Wait:
    """A job of more than one thread that was ready while a core stood idle."""

    job: str  # its rule and wildcards
    waited_seconds: float  # from ready to its start
    idle_core_seconds: float  # the idle cores over that time


@dataclass
class IdleWaits:
    """What a run's jobs of more than one thread cost it in idle cores while they waited."""

    core_seconds: float = 0.0  # idle core time while any of them waited; a moment two waited through counts once
    jobs: list[Wait] = field(default_factory=list)  # those that waited with a core idle, in order of start
    wide_jobs: int = 0  # the run's jobs of more than one thread, whether they waited or not


def _spans(run: Run, cores: int) -> list[tuple[datetime, datetime, int]]:
    """(start, end, threads) of each started job: a job without a finish time holds its threads to the log's last
    timestamp, as far as the log can tell; its threads at most the cores, as Snakemake runs it."""
    spans = []
    for job in run.jobs.values():
        end = run.finished_at.get(job.jobid, run.last_at)
        if job.started and end:
            spans.append((job.started, end, min(job.threads, cores)))
    return spans


def ready_at(run: Run, job: Job, maker: dict[str, int]) -> datetime | None:
    """When all of ``job``'s inputs were there: the last finish among the run's jobs that made any of them
    (``maker``: output path -> jobid), the run's start where this run made none; None where a maker's finish is
    not in the log."""
    finishes = [run.finished_at.get(maker[p]) for p in job.inputs if p in maker]
    if not finishes:
        return run.started
    return None if None in finishes else max(finishes)


def idle_core_seconds(spans: list[tuple[datetime, datetime, int]], cores: int, start: datetime, end: datetime
                      ) -> float:
    """The cores left idle from ``start`` to ``end``: at each moment, the cores less the threads of the jobs
    running then, counted where at least one core is idle (a job of two threads on two cores needs both free, so
    one idle core is what such a wait leaves unused)."""
    cuts = sorted({start, end} | {t for s, e, _ in spans for t in (s, e) if start < t < end})
    idle = 0.0
    for a, b in zip(cuts, cuts[1:]):
        free = cores - sum(n for s, e, n in spans if s <= a < e)
        if free >= 1:
            idle += free * (b - a).total_seconds()
    return idle


def _merged(intervals: list[tuple[datetime, datetime]]) -> list[tuple[datetime, datetime]]:
    """Overlapping intervals joined, so that time two jobs waited through is counted once."""
    out: list[tuple[datetime, datetime]] = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def idle_waits(run: Run, cores: int) -> IdleWaits:
    """How far the run broke "no job of two threads may wait while a core idles": each job of more than one
    thread waited from ready (ready_at) to its start, and the cores idle meanwhile (idle_core_seconds) are what
    that wait cost. A job without a finish time (a run cut off, or one still going) counts as running up to the
    log's last timestamp; a job that had not started is not in the log, so a wait still going is left out, and so
    is a job whose inputs' maker has no finish time in the log. The total counts each moment once, so where two
    jobs waited at once it is less than the sum of their own figures."""
    maker = {path: i for i, job in run.jobs.items() for path in job.outputs}
    spans = _spans(run, cores)
    result, waiting = IdleWaits(), []
    for job in sorted(run.jobs.values(), key=lambda j: (j.started or datetime.min, j.jobid)):
        if job.threads <= 1 or job.started is None:
            continue
        result.wide_jobs += 1
        ready = ready_at(run, job, maker)
        if ready is None or ready >= job.started:
            continue
        waiting.append((ready, job.started))
        idle = idle_core_seconds(spans, cores, ready, job.started)
        if idle > 0:
            waited = (job.started - ready).total_seconds()
            result.jobs.append(Wait(f"{job.rule} {job.wildcards}".strip(), waited, idle))
    result.core_seconds = sum(idle_core_seconds(spans, cores, a, b) for a, b in _merged(waiting))
    return result


def _medians(run: Run, cpu: dict[int, float], key) -> dict[str, float]:
    groups: dict[str, list[float]] = {}
    for i, seconds in cpu.items():
        groups.setdefault(key(run.jobs[i]), []).append(seconds)
    return {k: statistics.median(v) for k, v in groups.items()}


def write_rule_times(workdir, path) -> pl.DataFrame:
    """Every job of ``workdir``'s results with a benchmark file, whichever run made it, per rule and kind: jobs,
    median and total CPU seconds, to ``path`` (CSV). The rule and kind of a benchmark file are read from the run
    logs that started it."""
    job_of = {}
    for log in sorted(Path(workdir, ".snakemake", "log").glob("*.snakemake.log")):
        job_of |= {Path(workdir, j.benchmark).resolve(): j for j in parse(log).jobs.values() if j.benchmark}
    history: dict[tuple[str, str], list[float]] = {}
    for bench, job in job_of.items():
        cpu = cpu_seconds(bench)
        if cpu is not None:
            history.setdefault((job.rule, job.kind), []).append(cpu)
    if not history:
        raise FileNotFoundError(f"{workdir}: no run log names a job whose benchmark file is there to record")
    table = pl.DataFrame([{"rule": rule, "kind": kind, "jobs": len(cpu),
                           "median_cpu_seconds": round(statistics.median(cpu), 1), "cpu_seconds": round(sum(cpu), 1)}
                          for (rule, kind), cpu in sorted(history.items())])
    with atomic_path(path) as tmp:
        table.write_csv(tmp)
    return table


@dataclass
class Recorded:
    """A recorded run's prices: per rule (its jobs' mean CPU seconds) and per kind (their median)."""

    rules: dict[str, float] = field(default_factory=dict)
    kinds: dict[str, float] = field(default_factory=dict)


def read_rule_times(path) -> Recorded:
    """A recorded run's prices; empty where there is no record (a record written before kinds has rules only)."""
    if not Path(path).is_file():
        return Recorded()
    t = pl.read_csv(path)
    if "kind" not in t.columns:
        return Recorded(dict(t.select("rule", "median_cpu_seconds").iter_rows()))
    rules = t.group_by("rule").agg((pl.col("cpu_seconds").sum() / pl.col("jobs").sum()).alias("mean"))
    return Recorded(dict(rules.iter_rows()), dict(t.select("kind", "median_cpu_seconds").iter_rows()))


@dataclass
class Estimate:
    """Seconds left on the given cores if they stay busy. Jobs are priced, in this order of preference, from this
    run's finished jobs of their kind, from the recorded run's jobs of their kind (scaled by how much faster or
    slower this run's kinds have been than the record's), from this run's finished jobs of their rule; those left
    from the recorded run's jobs of their rule (given apart); jobs priced by none are counted by rule."""

    seconds: float = 0.0
    jobs: int = 0
    by_kind: int = 0  # of ``jobs``, those priced from this run's jobs of their own kind
    by_recorded_kind: int = 0  # and those from the record's jobs of their kind
    speed: float = 1.0  # this run's CPU seconds / the record's, median over the kinds both have
    recorded_seconds: float = 0.0
    recorded_jobs: int = 0
    unknown: dict[str, int] = field(default_factory=dict)

    @property
    def priced_seconds(self) -> float:
        """This run's part and the recorded-run part together."""
        return self.seconds + self.recorded_seconds


def estimate(run: Run, cores: int, cpu: dict[int, float], recorded: Recorded | None = None,
             pending: list[Job] | None = None, by_kind: bool = True) -> Estimate:
    """The time ``pending`` jobs still need (default: each rule's planned jobs less its finished ones, kinds
    unknown), priced from ``cpu`` (jobid -> CPU seconds of the finished jobs) and the ``recorded`` run."""
    recorded = recorded or Recorded()
    kinds = _medians(run, cpu, lambda j: j.kind) if by_kind else {}
    rules = _medians(run, cpu, lambda j: j.rule)
    est = Estimate()
    both = [kinds[k] / recorded.kinds[k] for k in kinds.keys() & recorded.kinds.keys() if recorded.kinds[k] > 0]
    est.speed = statistics.median(both) if both else 1.0
    if pending is None:
        finished_by_rule = Counter(run.jobs[i].rule for i in run.finished if i in run.jobs)
        pending = [Job(rule, -1, None) for rule, count in run.planned.items()
                   for _ in range(count - finished_by_rule.get(rule, 0))]
        kinds_known = False
    else:
        kinds_known = by_kind
    for job in pending:
        if kinds_known and job.kind in kinds:
            price, est.by_kind = kinds[job.kind], est.by_kind + 1
        elif kinds_known and job.kind in recorded.kinds:
            price, est.by_recorded_kind = recorded.kinds[job.kind] * est.speed, est.by_recorded_kind + 1
        elif job.rule in rules:
            price = rules[job.rule]
        elif job.rule in recorded.rules:
            est.recorded_seconds += recorded.rules[job.rule] / max(cores, 1)
            est.recorded_jobs += 1
            continue
        else:
            est.unknown[job.rule] = est.unknown.get(job.rule, 0) + 1
            continue
        est.seconds += price / max(cores, 1)
        est.jobs += 1
    return est


def plan(run: Run, workdir, timeout: float = 300) -> list[Job] | None:
    """The jobs a dry run of the run's own command would still run (running ones included), or None where the
    command is unknown or the dry run fails."""
    if not run.command:
        return None
    argv = shlex.split(run.command)
    try:
        dry = subprocess.run([argv[0], "-n", "--nolock", *argv[1:]], cwd=workdir, capture_output=True, text=True,
                             timeout=timeout)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if dry.returncode != 0:
        return None
    return list(parse_text(dry.stdout + dry.stderr).jobs.values())  # Snakemake lists the jobs on stderr


def replay(run: Run, workdir, cores: int, recorded: Recorded | None = None, shares=(0.25, 0.5, 0.75)
           ) -> pl.DataFrame:
    """On a finished run's log: at each share of its jobs finished, the time left as estimated from the jobs
    finished by then and ``recorded`` (another run's record), by kind and by rule alone (as before kinds),
    against the time the run really went on. Jobs running at that moment are priced whole, so both estimates
    lean high by up to one job per core."""
    order = sorted(run.finished_at.items(), key=lambda kv: kv[1])
    if not order or run.jobs.keys() - run.finished:
        raise ValueError(f"{run.log}: not a finished run (replay needs every job started and finished)")
    times = finished_times(run, workdir)
    end = order[-1][1]
    rows = []
    for share in shares:
        n = max(1, round(share * len(order)))
        done = {i for i, _ in order[:n]}
        pending = [j for i, j in run.jobs.items() if i not in done]
        known = {i: t for i, t in times.items() if i in done}
        kind, rule = (estimate(run, cores, cpu_of(known), recorded, pending, by_kind=b) for b in (True, False))
        # as a live run sees it then: the jobs started by then and not finished are the running ones
        then = order[n - 1][1]
        seen = Run(run.log, run.started, run.planned, {i: j for i, j in run.jobs.items() if j.started <= then})
        busy = utilisation_so_far(seen, known, then, cores)
        by_kind = kind.priced_seconds / 60
        rows.append({"share": share, "jobs_done": n, "estimate_by_rule_min": round(rule.priced_seconds / 60, 1),
                     "estimate_by_kind_min": round(by_kind, 1),
                     "utilisation_so_far": None if busy is None else round(busy, 2),
                     "estimate_by_kind_at_utilisation_min": None if not busy else round(by_kind / busy, 1),
                     "actual_min": round((end - then).total_seconds() / 60, 1),
                     "jobs_unpriced": sum(kind.unknown.values())})
    return pl.DataFrame(rows)


def _minutes(seconds: float) -> str:
    m = round(seconds / 60)
    return f"{m // 60} h {m % 60:02d} min" if m >= 60 else f"{m} min"


def lines(workdir=".", cores: int = 2, now: datetime | None = None, dry_run: bool = True) -> list[str]:
    """``dry_run``: list the jobs still to come with a dry run of the run's command, so each is priced by its
    kind; without it (or where it fails) they are priced by rule."""
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
    pending = plan(run, workdir) if dry_run and run.done < run.total else None
    times = finished_times(run, workdir)
    est = estimate(run, cores, cpu_of(times), read_rule_times(Path(workdir, RULE_TIMES)), pending)
    busy = utilisation_so_far(run, times, now, cores)
    how = (f"{est.by_kind} priced by the median CPU time of this run's finished jobs of their kind, "
           f"{est.by_recorded_kind} by their kind's in the recorded run x {est.speed:.2f} (this run's speed "
           "against it), the rest by their rule's" if pending is not None else
           "for each rule, the median CPU time of this run's finished jobs x its jobs left")
    at_pace = (f"; at this run's utilisation so far ({100 * busy:.0f} % of the cores busy), about "
               f"{_minutes(est.priced_seconds / busy)} for these and the recorded-run part"
               if busy else "")
    out.append(f"left: {run.total - run.done} jobs; {est.jobs} of them about {_minutes(est.seconds)} on {cores} "
               f"cores ({how}; cores kept busy){at_pace}")
    if est.recorded_jobs:
        out.append(f"  {est.recorded_jobs} more, of rules with no finished job yet, about "
                   f"{_minutes(est.recorded_seconds)} as the recorded run ({RULE_TIMES}) priced their rules (its "
                   "profile and machine; another costs otherwise)")
    if est.unknown:
        out.append(f"  the other {sum(est.unknown.values())}, of rules with no finished job and no record, are not "
                   "in that figure: " + ", ".join(f"{rule} x{n}" for rule, n in sorted(est.unknown.items())))
    return out
