from ocpipe.frames import render
from ocpipe.util import runlog
from ocpipe.util.atomic import write_json

w = snakemake.wildcards
with runlog.to_file(snakemake.log[0]):
    stats = render.render_shard(w.task, w.cams, int(w.res), snakemake.input.h5, int(w.shard),
                                snakemake.params.cfg["frames"]["shards"], snakemake.params.cfg, snakemake.output.store)
    write_json(snakemake.output.stats, stats)
