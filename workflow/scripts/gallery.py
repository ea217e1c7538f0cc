from ocpipe.gallery import build
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    import torch

    torch.set_num_threads(snakemake.threads)
    p = snakemake.params
    print(build.build_experiment(
        snakemake.wildcards.exp, p.policy, p.cfg, p.gallery, p.near_miss_m, p.seed, p.tables,
        classes=dict(zip(p.runs, snakemake.input.classes)), runs=p.runs,
        frames_store=snakemake.input.get("frames"), encoder_checkpoint=snakemake.input.get("encoder") or None,
        videos_dir=snakemake.output.videos, sheets_dir=snakemake.output.sheets, manifest=snakemake.output.manifest))
