from ocpipe.study import report
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(report.classify_episodes(list(snakemake.input.episodes), snakemake.params.task, snakemake.params.rules,
                                   snakemake.output.classes))
