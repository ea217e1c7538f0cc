from ocpipe.study import report
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(report.write_table(snakemake.params.cfg, snakemake.wildcards.table, snakemake.output.csv,
                             snakemake.output.md))
