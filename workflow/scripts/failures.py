from ocpipe.evaluation import taxonomy
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(taxonomy.classify_episodes(list(snakemake.input.episodes), snakemake.params.task, snakemake.params.rules,
                                   snakemake.output.classes))
