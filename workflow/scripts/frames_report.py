import json
from pathlib import Path

from ocpipe.frames import report
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    seconds = [json.loads(Path(p).read_text())["seconds"] for p in snakemake.input.stats]
    r = snakemake.params.report
    summary = report.write_report(snakemake.input.store, snakemake.output.json, snakemake.output.png,
                                  r["contact_sheet_episodes"], r["contact_sheet_steps"], seconds)
    print(json.dumps(summary, indent=2))
