from ocpipe.features import attention
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    attention.attention_maps(snakemake.input.frames, snakemake.input.features,
                             [tuple(p) for p in snakemake.params.pairs], snakemake.output.png)
