from pathlib import Path

from ocpipe.policy import training
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    table = training.train(snakemake.params.policy, snakemake.params.seed, snakemake.input.features,
                           snakemake.input.frames, Path(snakemake.output.log).parent, threads=snakemake.threads,
                           scenes_path=getattr(snakemake.input, "scenes", None),
                           camera_approx=snakemake.params.camera_approx)
    print(table)
