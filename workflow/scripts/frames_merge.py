from ocpipe import frames_store, runlog

with runlog.to_file(snakemake.log[0]):
    frames_store.merge(snakemake.input.stores, snakemake.output.store, snakemake.params.chunk_frames)
    problems = frames_store.check_contract(snakemake.output.store)
    if problems:
        raise RuntimeError(f"{snakemake.output.store} breaks the store contract: " + "; ".join(problems))
