"""A run's CPU as the kernel counts it, beside the benchmark files' count.

Snakemake's benchmark files sample a job's process tree: every half second for its first 15 s, then every 30 s
(snakemake.benchmark), so the CPU a job spends after its last sample is never counted, up to 30 s of it a job. On
the main job from a fresh clone (140 jobs, many of them a minute or less) the files summed to 110 core-minutes
where `time make main` counted 132. The Snakefile's onsuccess and onerror handlers therefore record, when the run
ends, ``getrusage(RUSAGE_CHILDREN)`` of the Snakemake process: the user and system time of every process it
started and waited for (each local job with everything the job ran), to the clock tick. A run on a cluster
executor runs its jobs elsewhere, so there is nothing to count and nothing is recorded."""

from __future__ import annotations

import json
import resource
from pathlib import Path

from .. import paths
from ..util.atomic import write_json

FOLDER = paths.RESULTS + "/logs/run_cpu"  # one {run log's name}.json a run
LOG_SUFFIX = ".snakemake.log"


def path_of(log: Path | str, workdir: Path | str = ".") -> Path:
    """Where the count of the run that wrote ``log`` (a .snakemake/log/*.snakemake.log) is kept."""
    name = Path(log).name
    if not name.endswith(LOG_SUFFIX):
        raise ValueError(f"{log}: not a Snakemake run log (*{LOG_SUFFIX})")
    return Path(workdir, FOLDER, name.removesuffix(LOG_SUFFIX) + ".json")


def record(log_files, local: bool, workdir: Path | str = ".") -> Path | None:
    """Keep this process's children's CPU seconds for the run whose log is ``log_files[0]`` (Snakemake hands its
    onsuccess/onerror handlers a list); None, writing nothing, for a run without a log or not run locally."""
    if not local or not log_files:
        return None
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    own = resource.getrusage(resource.RUSAGE_SELF)
    out = path_of(log_files[0], workdir)
    write_json(out, {"log": Path(log_files[0]).name,
                     "jobs_cpu_seconds": round(children.ru_utime + children.ru_stime, 2),
                     "snakemake_cpu_seconds": round(own.ru_utime + own.ru_stime, 2)})
    return out


def read(log: Path | str, workdir: Path | str = ".") -> dict | None:
    """The count ``record`` kept for the run that wrote ``log``; None where it kept none (a run before it did)."""
    found = path_of(log, workdir)
    if not found.exists():
        return None
    data = json.loads(found.read_text())
    missing = {"jobs_cpu_seconds", "snakemake_cpu_seconds"} - set(data)
    if missing:
        raise ValueError(f"{found}: no {', '.join(sorted(missing))} (written by ocpipe.bookkeeping.run_cpu.record)")
    return data
