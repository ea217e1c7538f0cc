import json

from ocpipe.evaluation import best
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(json.dumps(best.write_best(list(snakemake.input.sweep), snakemake.output.json, snakemake.input.train_log,
                                     snakemake.params.alpha),
                     indent=2))
