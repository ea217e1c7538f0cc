from ocpipe.features import scenes
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    print(scenes.merge_scenes(snakemake.input.shards, snakemake.output.store))
