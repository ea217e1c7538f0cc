from ocpipe import frames, runlog
from ocpipe.atomic import write_json

w = snakemake.wildcards
with runlog.to_file(snakemake.log[0]):
    stats = frames.render_shard(w.task, w.cams, int(w.res), snakemake.input.h5, int(w.shard),
                                snakemake.params.cfg["frames"]["shards"], snakemake.params.cfg, snakemake.output.store)
    write_json(snakemake.output.stats, stats)
