"""Command-line helpers around the workflow: `ocpipe check-config`, `ocpipe check-store`, `ocpipe summary`,
`ocpipe config-docs`, `ocpipe compute`, `ocpipe record`."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .config import validate
from .config.errors import ConfigError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ocpipe", description=__doc__)
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("check-config", help="validate config files (later files override earlier ones)")
    p.add_argument("files", nargs="*", default=["config/config.yaml"])
    p = sub.add_parser("check-store", help="check a frames store against the contract and print its summary")
    p.add_argument("store")
    p = sub.add_parser("summary", help="print the headline figures of everything built under a results folder")
    p.add_argument("results", nargs="?", default="results")
    p = sub.add_parser("config-docs", help="regenerate config/README.md from the config schema and config/config.yaml")
    p.add_argument(
        "--check", action="store_true", help="only check that config/README.md is up to date (exit 1 if not)"
    )
    p = sub.add_parser("compute", help="where a results folder's time went: print (and write) its compute table")
    p.add_argument("results", nargs="?", default="results")
    p.add_argument("--config", nargs="*", default=["config/config.yaml"], help="config files of that run")
    p = sub.add_parser("record", help="copy a whole run's tables, findings and compute table into docs/results/")
    p.add_argument("results", nargs="?", default="results")
    p.add_argument("--out", default="docs/results")
    p.add_argument("--command", default="time snakemake --cores 2 all", help="the command that made the run")
    p.add_argument("--config", nargs="*", default=["config/config.yaml"], help="config files of that run")
    args = parser.parse_args(argv)

    if args.cmd == "record":
        from .study import record

        try:
            files = record.write(validate.load(*args.config), args.results, args.out, args.command,
                                 record.commit_of(Path(args.results).resolve().parent))
        except FileNotFoundError as err:
            print(f"ocpipe: {err}", file=sys.stderr)
            return 1
        print(f"recorded {len(files)} files in {args.out}")
        return 0

    if args.cmd == "compute":
        from .study import compute

        out = f"{args.results}/tables"
        compute.write(validate.load(*args.config), f"{args.results}/benchmarks", f"{out}/compute.csv",
                      f"{out}/compute.md")
        print(Path(out, "compute.md").read_text())
        return 0

    if args.cmd == "config-docs":
        from .config import docs

        return docs.main(check=args.check)

    if args.cmd == "summary":
        from .study.summary import summary_lines

        print("\n".join(summary_lines(args.results)))
        return 0

    if args.cmd == "check-config":
        try:
            validate.load(*args.files)
        except ConfigError as err:
            print(f"ocpipe: {err}", file=sys.stderr)
            return 1
        print("ok: " + " + ".join(args.files))
        return 0

    from .frames import report, store

    problems = store.check_contract(args.store)
    for problem in problems:
        print(f"contract: {problem}", file=sys.stderr)
    if not problems:
        print(json.dumps(report.summarize(args.store), indent=2))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
