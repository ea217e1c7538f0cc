from ocpipe.study import report
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(report.write_findings(snakemake.params.cfg, snakemake.wildcards.scope, snakemake.output.csv,
                                snakemake.output.md))
