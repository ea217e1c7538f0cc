import json

from ocpipe.evaluation import jobs
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(json.dumps(jobs.write_best(list(snakemake.input.sweep), snakemake.output.json, snakemake.input.train_log,
                                     snakemake.params.alpha),
                     indent=2))
