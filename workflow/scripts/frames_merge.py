from ocpipe.frames import store
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    store.merge(snakemake.input.stores, snakemake.output.store, snakemake.params.chunk_frames)
    problems = store.check_contract(snakemake.output.store)
    if problems:
        raise RuntimeError(f"{snakemake.output.store} breaks the store contract: " + "; ".join(problems))
