# Frames: env-state-aligned replay of every demo, rendered natively with the study's cameras, in shards that
# run as separate jobs, merged into results/frames/{task}_{cams}_{res}.zarr (contract: README.md).


rule frames_shard:
    input:
        h5="results/demos/{task}.h5",
        json="results/demos/{task}.json",
    output:
        store=temp(directory("results/frames/shards/{task}_{cams}_{res}/shard{shard}.zarr")),
        stats="results/frames/shards/{task}_{cams}_{res}/shard{shard}.json",
    log:
        "results/logs/frames_shard/{task}_{cams}_{res}_shard{shard}.log",
    benchmark:
        "results/benchmarks/frames_shard/{task}_{cams}_{res}_shard{shard}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("frames")
    resources:
        **resources_of("frames"),
    params:
        cfg=cfg("sim", "frames", "cameras", "camera_approx"),
    script:
        "../scripts/frames_shard.py"


rule frames_merge:
    input:
        stores=expand(
            "results/frames/shards/{{task}}_{{cams}}_{{res}}/shard{shard}.zarr",
            shard=range(config["frames"]["shards"]),
        ),
    output:
        store=directory("results/frames/{task}_{cams}_{res}.zarr"),
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
        store="results/frames/{task}_{cams}_{res}.zarr",
        stats=expand(
            "results/frames/shards/{{task}}_{{cams}}_{{res}}/shard{shard}.json",
            shard=range(config["frames"]["shards"]),
        ),
    output:
        json="results/frames/{task}_{cams}_{res}.report.json",
        png="results/frames/{task}_{cams}_{res}.contact.png",
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
