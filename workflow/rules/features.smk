# Features: every frame of a frames store encoded once by a frozen encoder, stored per frame in Zarr chunks,
# with slot diagnostics, decomposition scores against simulator segmentation, and attention-map figures.


rule features:
    input:
        frames=paths.FRAMES_STORE,
        ckpt=lambda w: encoder_checkpoint(w.encoder),
    output:
        store=directory(paths.FEATURES_STORE),
    log:
        "results/logs/features/{task}_{cams}_{res}_{encoder}.log",
    benchmark:
        "results/benchmarks/features/{task}_{cams}_{res}_{encoder}.tsv"
    priority: store_priority("features")
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("features")
    resources:
        **resources_of("features"),
    params:
        # only what encoding reads: the encoder's own config sections and the encoding keys of `features` (not the
        # attention maps' pairs or the diagnostics' probe settings)
        encoders=features_encoders,
        features=job_params.encoding(config),
    script:
        "../scripts/features.py"


rule scenes_shard:
    input:
        frames=paths.FRAMES_STORE,
        ckpt=lambda w: encoder_checkpoint(w.encoder),
    output:
        store=temp(directory(paths.SCENES_SHARD)),
    log:
        "results/logs/scenes_shard/{task}_{cams}_{res}_{encoder}_shard{shard}.log",
    benchmark:
        "results/benchmarks/scenes_shard/{task}_{cams}_{res}_{encoder}_shard{shard}.tsv"
    priority: store_priority("frames")
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("frames")
    resources:
        **resources_of("frames"),
    params:
        config=scene_params,
        dtype=config["features"]["dtype"],
        seed=config["seed"],
    script:
        "../scripts/scenes_shard.py"


rule scenes:
    input:
        shards=expand(paths.SCENES_SHARD, shard=range(config["scenes"]["shards"]), allow_missing=True),
    output:
        store=directory(paths.SCENES_STORE),
    log:
        "results/logs/scenes/{task}_{cams}_{res}_{encoder}.log",
    benchmark:
        "results/benchmarks/scenes/{task}_{cams}_{res}_{encoder}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    script:
        "../scripts/scenes.py"


rule features_diagnostics:
    input:
        frames=paths.FRAMES_STORE,
        features=paths.FEATURES_STORE,
    output:
        json=paths.FEATURES_DIAGNOSTICS,
    log:
        "results/logs/features_diagnostics/{task}_{cams}_{res}_{encoder}.log",
    benchmark:
        "results/benchmarks/features_diagnostics/{task}_{cams}_{res}_{encoder}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        holdout=diagnostics_holdout,
        probe_holdout=config["features"]["probe_holdout"],
        probe_mlp_epochs=config["features"]["probe_mlp_epochs"],
        seed=config["seed"],
    script:
        "../scripts/features_diagnostics.py"


rule attention_maps:
    input:
        frames=paths.FRAMES_STORE,
        features=paths.FEATURES_STORE,
    output:
        png=paths.ATTENTION_FIGURE,
    log:
        "results/logs/attention_maps/{task}_{cams}_{res}_{encoder}.log",
    benchmark:
        "results/benchmarks/attention_maps/{task}_{cams}_{res}_{encoder}.tsv"
    wildcard_constraints:
        encoder="slots_ssl|spot",
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        pairs=config["features"]["attention_pairs"],
    script:
        "../scripts/attention_maps.py"
