# rule compute: where the run's time went, from the rules' benchmark files
from ocpipe.bookkeeping import compute, progress
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(compute.write(snakemake.params.cfg, snakemake.params.benchmarks, snakemake.output.csv,
                        snakemake.output.md, progress.run_cores(".")))
