from ocpipe import attention_figure, runlog

with runlog.to_file(snakemake.log[0]):
    attention_figure.attention_maps(snakemake.input.frames, snakemake.input.features,
                                    [tuple(p) for p in snakemake.params.pairs], snakemake.output.png)
