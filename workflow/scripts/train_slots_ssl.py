import json

from ocpipe.encoders import training
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    report = training.train_stage(
        list(snakemake.input.stores), snakemake.params.enc, snakemake.params.seed, snakemake.output.ckpt,
        snakemake.output.curve, snakemake.output.eval, threads=snakemake.threads)
    print(json.dumps(report, indent=2))
