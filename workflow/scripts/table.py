from ocpipe import report, runlog

with runlog.to_file(snakemake.log[0]):
    print(report.write_table(snakemake.params.cfg, snakemake.wildcards.table, snakemake.output.csv,
                             snakemake.output.md))
