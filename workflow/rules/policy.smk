# Policy training: one job per policy, K per named experiment (config `experiments`, overrides of `policy`;
# `replicates`).


rule train:
    input:
        unpack(train_inputs),
    output:
        checkpoints=directory(paths.CHECKPOINTS),
        log=paths.TRAIN_LOG,
    log:
        "results/logs/train/{exp}.log",
    benchmark:
        "results/benchmarks/train/{exp}.tsv"
    priority: policy_priority("train")
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("train")
    resources:
        **resources_of("train"),
    params:
        policy=policy_of,
        seed=training_seed,
        camera_approx=lambda w: training_camera_approx(policy_of(w)),
    script:
        "../scripts/train.py"
