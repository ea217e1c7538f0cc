from ocpipe import features, runlog
from ocpipe.encoders import registry

w = snakemake.wildcards
with runlog.to_file(snakemake.log[0]):
    encoder = registry.build(w.encoder, snakemake.params.encoders, snakemake.input.frames,
                             snakemake.input.ckpt or None)
    f = snakemake.params.features
    stats = features.encode_store(encoder, snakemake.input.frames, snakemake.output.store, f["batch_size"],
                                  f["chunk_frames"], threads=snakemake.threads, dtype=f["dtype"],
                                  device=f["device"])
    print(stats)
