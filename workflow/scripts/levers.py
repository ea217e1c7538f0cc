# rule levers: the levers table
from ocpipe.study import levers
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(levers.write(snakemake.params.cfg, snakemake.params.files, snakemake.output.csv, snakemake.output.md))
