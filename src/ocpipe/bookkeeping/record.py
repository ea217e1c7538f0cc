"""The record of a full run: its tables and findings copied as the pipeline wrote them into a folder under version
control (docs/results/), its compute table written again from the whole run, with the commit and command that made
them, and the CPU time of each rule and kind of job (rule_times.csv), by which `ocpipe progress` prices a later
run's jobs before any of their kind has finished."""

from __future__ import annotations

import re
import shutil
import subprocess
from datetime import datetime, timezone
from pathlib import Path

from ..util.atomic import atomic_path
from . import compute, progress


def recorded_files(config: dict, tables_dir) -> list[Path]:
    """Every table of the config, the findings and the compute table, as .csv and .md; a missing one is an error
    naming it (a record is of a whole run, never of part of one)."""
    names = [*config["tables"], "findings", "compute"]
    files = [Path(tables_dir, f"{n}.{ext}") for n in names for ext in ("csv", "md")]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise FileNotFoundError("not a whole run's tables (build them with `snakemake --cores 2 all`); missing: "
                                + ", ".join(missing))
    return files


def commit_of(repo) -> str:
    """HEAD's hash, marked where the working tree differs from it (the record then is not of that commit alone)."""
    git = ["git", "-C", str(repo)]
    head = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode:
        raise FileNotFoundError(f"{repo} is not a git checkout: a record names the commit that made it")
    dirty = subprocess.run([*git, "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True,
                           check=True).stdout.strip()
    return f"{head.stdout.strip()} (with uncommitted changes)" if dirty else head.stdout.strip()


# a block's body: whole lines, none of them a marker, so an empty block never swallows the next one
MARKED = re.compile(r"(<!-- record: (?P<name>[\w.]+) -->\n)(?:(?!<!-- /?record)[^\n]*\n)*(<!-- /record -->)")


def fill_marked(text: str, out_dir) -> str:
    """``text`` with each block between ``<!-- record: NAME -->`` and ``<!-- /record -->`` replaced by the recorded
    file NAME (so README shows the record's own tables, never a hand copy); a NAME not recorded is an error."""
    def block(m: re.Match) -> str:
        f = Path(out_dir, m["name"])
        if not f.is_file():
            raise FileNotFoundError(f"a record block names {m['name']}, which is not in {out_dir}")
        return m.group(1) + f.read_text().strip() + "\n" + m.group(3)
    return MARKED.sub(block, text)


def write(config: dict, results, out_dir, command: str, commit: str | None = None, readme=None) -> list[Path]:
    """Copy the run's tables into ``out_dir`` (replacing what was there), write its rule times where the run's
    logs are beside ``results`` (its workdir), and its README.md; ``commit`` defaults to that of the workdir.
    ``readme``: a file whose record blocks (fill_marked) are refilled from the new record."""
    files = recorded_files(config, Path(results, "tables"))
    workdir = Path(results).resolve().parent
    commit = commit or commit_of(workdir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*"):
        if old.is_file() and old.suffix in (".csv", ".md"):
            old.unlink()
    for f in files:
        with atomic_path(out / f.name) as tmp:
            shutil.copyfile(f, tmp)
    bench_dir = Path(results, "benchmarks")
    recomputed = bench_dir.is_dir()
    if recomputed:  # the run's own compute job ran before its last jobs and before the run kept its CPU
        compute.write(config, bench_dir, out / "compute.csv", out / "compute.md", progress.run_cores(workdir),
                      workdir)
    try:
        progress.write_rule_times(workdir, out / progress.RULE_TIMES.name)
        rule_times = True
    except FileNotFoundError:  # the results folder was moved away from its run logs: the tables still stand
        rule_times = False
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d")
    note = (f"# The last full run\n\nCommit `{commit}`, profile {config.get('profile', '?')}, recorded {when}.\n"
            f"Command, from a fresh clone:\n\n```bash\n{command}\n```\n\n"
            "Every file here is the pipeline's own output, never edited: the study's tables (`table5_*`) and the "
            "findings this run reproduces (`findings`), copied by `ocpipe record`, and where its time went "
            + ("(`compute`), which `ocpipe record` writes again from the whole run's benchmark files and logs (the "
               "run's own compute job ran before its last jobs ended, and before the run kept its CPU as the kernel "
               "counted it).\n" if recomputed else "(`compute`), as the run's compute job wrote it.\n")
            + ("`rule_times.csv` is the jobs and CPU seconds of each rule and kind of job (the rule's wildcards less "
               "replicate, shard, run and checkpoint) in that run, from its benchmark files; `ocpipe progress` "
               "prices a later run's jobs by it until their own kind has a finished job.\n"
               if rule_times else ""))
    with atomic_path(out / "README.md") as tmp:
        tmp.write_text(note)
    if readme is not None:
        text = fill_marked(Path(readme).read_text(), out)
        with atomic_path(readme) as tmp:
            tmp.write_text(text)
    return [out / f.name for f in files]
