from ocpipe import report, runlog

with runlog.to_file(snakemake.log[0]):
    print(report.classify_episodes(list(snakemake.input.episodes), snakemake.params.task, snakemake.params.rules,
                                   snakemake.output.classes))
