import json
from pathlib import Path

from ocpipe.demos import merge
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    reports = [json.loads(Path(p).read_text()) for p in snakemake.input.reports]
    merge.merge(snakemake.input.h5, snakemake.output.h5, reports, snakemake.output.report)
