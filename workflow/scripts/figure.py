from ocpipe import report, runlog

with runlog.to_file(snakemake.log[0]):
    report.write_figure(snakemake.params.cfg, snakemake.wildcards.figure, snakemake.output.png)
