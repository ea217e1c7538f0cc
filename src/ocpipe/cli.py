"""Command-line helpers around the workflow: `ocpipe check-config`, `ocpipe check-store`, `ocpipe summary`,
`ocpipe config-docs`, `ocpipe compute`, `ocpipe record`, `ocpipe progress`."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .config import validate
from .config.errors import ConfigError

CONFIG_HELP = "config files of that run (later files override earlier ones)"


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="ocpipe", description=__doc__)
    sub = top.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("check-config", help="validate config files (later files override earlier ones)")
    p.add_argument("files", nargs="*", default=["config/config.yaml"])
    p = sub.add_parser("check-store", help="check a frames store against the contract and print its summary")
    p.add_argument("store")
    p = sub.add_parser("summary", help="print the headline figures of everything built under a results folder")
    p.add_argument("results", nargs="?", default="results")
    p = sub.add_parser("config-docs", help="regenerate config/README.md from the config schema and config/config.yaml")
    p.add_argument("--check", action="store_true", help="only check that config/README.md is up to date (exit 1 if "
                   "not)")
    p = sub.add_parser("compute", help="where a results folder's time went: write and print its compute table")
    p.add_argument("results", nargs="?", default="results")
    p.add_argument("--cores", type=int, default=None, help="the cores the run was given (snakemake --cores), for its "
                   "utilisation; default: what the newest run log under the results' folder says")
    p.add_argument("--config", nargs="*", default=["config/config.yaml"], help=CONFIG_HELP)
    p = sub.add_parser("progress", help="where a workflow run stands (from a second terminal): jobs done, the running "
                       "jobs' progress bars, an estimate of the time left")
    p.add_argument("workdir", nargs="?", default=".", help="the folder the run was started in")
    p.add_argument("--cores", type=int, default=2, help="the cores the run was given (snakemake --cores)")
    p.add_argument("--no-dry-run", action="store_true", help="price the jobs left by rule, without the dry run "
                   "that lists them so each is priced by its kind (about a minute on the whole study's graph)")
    p.add_argument("--replay", action="store_true", help="check the pricing on the newest run log, a finished run: "
                   "at 25, 50 and 75 %% of its jobs, the estimate from the jobs finished by then against the real "
                   "time left")
    p = sub.add_parser("record", help="copy a whole run's tables and findings into docs/results/ and write its "
                       "compute table there from the whole run")
    p.add_argument("results", nargs="?", default="results")
    p.add_argument("--out", default="docs/results")
    p.add_argument("--command", default="time snakemake --cores 2 all", help="the command that made the run")
    p.add_argument("--readme", default="README.md", help="a file whose `<!-- record: NAME -->` blocks show the "
                   "recorded NAME (default README.md; '' for none)")
    p.add_argument("--config", nargs="*", default=["config/config.yaml"], help=CONFIG_HELP)
    return top


def check_config(args) -> int:
    from .study.findings import check_config as check_tables

    check_tables(validate.load(*args.files))  # the tables the registry defines, with the rows the findings compare
    print("ok: " + " + ".join(args.files))
    return 0


def check_store(args) -> int:
    from .frames import report, store

    problems = store.check_contract(args.store)
    for problem in problems:
        print(f"contract: {problem}", file=sys.stderr)
    if not problems:
        print(json.dumps(report.summarize(args.store), indent=2))
    return 1 if problems else 0


def summary(args) -> int:
    from .study.summary import summary_lines

    print("\n".join(summary_lines(args.results)))
    return 0


def config_docs(args) -> int:
    from .config import docs

    return docs.main(check=args.check)


def compute(args) -> int:
    from .bookkeeping import compute, progress

    out = Path(args.results, "tables")
    cores = args.cores or progress.run_cores(Path(args.results).resolve().parent)
    compute.write(validate.load(*args.config), Path(args.results, "benchmarks"), out / "compute.csv",
                  out / "compute.md", cores)
    print((out / "compute.md").read_text())
    return 0


def record(args) -> int:
    from .bookkeeping import record

    files = record.write(validate.load(*args.config), args.results, args.out, args.command,
                         readme=args.readme or None)
    print(f"recorded {len(files)} files in {args.out}")
    return 0


def progress(args) -> int:
    from .bookkeeping import progress

    if args.replay:
        log = progress.newest_log(args.workdir)
        print(f"{log}, on {args.cores} cores: minutes left, estimated and real")
        recorded = progress.read_rule_times(Path(args.workdir, progress.RULE_TIMES))
        table = progress.replay(progress.parse(log), args.workdir, args.cores, recorded)
        print(" | ".join(table.columns))
        for row in table.iter_rows():
            print(" | ".join("-" if v is None else str(v) for v in row))
        return 0
    print("\n".join(progress.lines(args.workdir, args.cores, dry_run=not args.no_dry_run)))
    return 0


COMMANDS = {"check-config": check_config, "check-store": check_store, "summary": summary,
            "config-docs": config_docs, "compute": compute, "record": record, "progress": progress}


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return COMMANDS[args.cmd](args)
    except (ConfigError, FileNotFoundError) as err:
        print(f"ocpipe: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
