# Frames: env-state-aligned replay of every demo, rendered natively with the study's cameras, in shards that
# run as separate jobs, merged into results/frames/{task}_{cams}_{res}.zarr (contract: docs/pipeline.md).


rule frames_shard:
    input:
        h5=f"{paths.DEMOS}.h5",
        json=f"{paths.DEMOS}.json",
    output:
        store=temp(directory(f"{paths.FRAMES_SHARD}.zarr")),
        stats=f"{paths.FRAMES_SHARD}.json",
    log:
        "results/logs/frames_shard/{task}_{cams}_{res}_shard{shard}.log",
    benchmark:
        "results/benchmarks/frames_shard/{task}_{cams}_{res}_shard{shard}.tsv"
    priority: store_priority("frames")
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("frames")
    resources:
        **resources_of("frames"),
    params:
        cfg=frames_shard_params,
    script:
        "../scripts/frames_shard.py"


rule frames_merge:
    input:
        stores=expand(
            f"{paths.FRAMES_SHARD}.zarr",
            shard=range(config["frames"]["shards"]),
            allow_missing=True,
        ),
    output:
        store=directory(paths.FRAMES_STORE),
    log:
        "results/logs/frames_merge/{task}_{cams}_{res}.log",
    benchmark:
        "results/benchmarks/frames_merge/{task}_{cams}_{res}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        chunk_frames=config["frames"]["chunk_frames"],
    script:
        "../scripts/frames_merge.py"


rule frames_report:
    input:
        store=paths.FRAMES_STORE,
        stats=expand(
            f"{paths.FRAMES_SHARD}.json",
            shard=range(config["frames"]["shards"]),
            allow_missing=True,
        ),
    output:
        json=paths.FRAMES_REPORT,
        png=paths.FRAMES_CONTACT,
    log:
        "results/logs/frames_report/{task}_{cams}_{res}.log",
    benchmark:
        "results/benchmarks/frames_report/{task}_{cams}_{res}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        report=config["report"],
    script:
        "../scripts/frames_report.py"
