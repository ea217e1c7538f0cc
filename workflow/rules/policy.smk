# Policy training: one job per named experiment (config `experiments`, overrides of `policy`).


rule train:
    input:
        features=lambda w: f"results/features/{_exp.features_store(policy_of(w))}.zarr",
        frames=lambda w: f"results/frames/{_exp.frames_store(policy_of(w))}.zarr",
    output:
        checkpoints=directory("results/runs/{exp}/checkpoints"),
        log="results/runs/{exp}/train_log.parquet",
    log:
        "results/logs/train/{exp}.log",
    benchmark:
        "results/benchmarks/train/{exp}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("train")
    resources:
        **resources_of("train"),
    params:
        policy=policy_of,
        seed=config["seed"],
    script:
        "../scripts/train.py"
