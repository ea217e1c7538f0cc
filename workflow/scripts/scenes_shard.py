from ocpipe.encoders import registry
from ocpipe.features import scenes
from ocpipe.util import runlog

w, p = snakemake.wildcards, snakemake.params
with runlog.to_file(snakemake.log[0]):
    encoder = registry.build(w.encoder, p.config["encoders"], snakemake.input.frames, snakemake.input.ckpt or None)
    s = p.config["scenes"]
    print(scenes.render_scenes(encoder, p.config, w.task, w.cams, int(w.res), snakemake.input.frames,
                               snakemake.output.store, s["count"], s["seed_start"], p.seed, dtype=p.dtype,
                               near_fraction=s["near_fraction"], near_radius=s["near_radius"], shard=int(w.shard),
                               shards=s["shards"]))
