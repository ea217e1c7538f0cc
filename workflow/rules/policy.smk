# Policy training: one job per named experiment (config `experiments`, overrides of `policy`).


rule train:
    input:
        features=lambda w: paths.features_store(_exp.features_store(policy_of(w))),
        frames=lambda w: paths.frames_store(_exp.frames_store(policy_of(w))),
    output:
        checkpoints=directory(paths.CHECKPOINTS),
        log=paths.TRAIN_LOG,
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
