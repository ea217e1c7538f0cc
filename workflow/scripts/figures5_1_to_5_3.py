from ocpipe.study import report
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    report.write_figures5_1_to_5_3(snakemake.params.cfg, o.fig5_1, o.fig5_2, o.fig5_3)
