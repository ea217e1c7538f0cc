import json

from ocpipe import evaluation_jobs, runlog

with runlog.to_file(snakemake.log[0]):
    print(json.dumps(evaluation_jobs.write_best(list(snakemake.input.sweep), snakemake.output.json,
                                                       snakemake.input.train_log), indent=2))
