from ocpipe import report, runlog

with runlog.to_file(snakemake.log[0]):
    print(report.write_table5_1(snakemake.params.rows, snakemake.output.csv, snakemake.output.md))
