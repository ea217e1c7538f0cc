from ocpipe.study import report
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    report.write_figure(snakemake.params.cfg, snakemake.wildcards.figure, snakemake.output.png)
