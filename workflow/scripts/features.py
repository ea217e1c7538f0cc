from ocpipe.encoders import registry
from ocpipe.features import encode
from ocpipe.util import runlog

w = snakemake.wildcards
with runlog.to_file(snakemake.log[0]):
    encoder = registry.build(w.encoder, snakemake.params.encoders, snakemake.input.frames,
                             snakemake.input.ckpt or None)
    f = snakemake.params.features
    stats = encode.encode_store(encoder, snakemake.input.frames, snakemake.output.store, f["batch_size"],
                                f["chunk_frames"], threads=snakemake.threads, dtype=f["dtype"], device=f["device"])
    print(stats)
