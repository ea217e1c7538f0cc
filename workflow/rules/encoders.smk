# Encoders that the workflow trains itself: the offline `slots_ssl` default (and, with only DINO weights given,
# SPOT's slot module on top of frozen DINO).


rule train_slots_ssl:
    input:
        stores=[paths.frames_store(s) for s in config["encoders"]["slots_ssl"]["train_stores"]],
    output:
        ckpt=f"{paths.SLOTS_SSL}/model.pt",
        curve=f"{paths.SLOTS_SSL}/train_curve.parquet",
        eval=f"{paths.SLOTS_SSL}/held_out_decomposition.json",
    log:
        "results/logs/train_slots_ssl.log",
    benchmark:
        "results/benchmarks/train_slots_ssl.tsv"
    priority: scheduling.task_priority(config["policy"]["task"], config, threads_of("train_slots_ssl"))
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("train_slots_ssl")
    resources:
        **resources_of("train_slots_ssl"),
    params:
        enc=config["encoders"]["slots_ssl"],
        seed=config["seed"],
    script:
        "../scripts/train_slots_ssl.py"


rule train_spot_slots_on_dino:
    """Only when encoders.spot.dino_checkpoint is given without SPOT's own checkpoint."""
    input:
        stores=[paths.frames_store(s) for s in config["encoders"]["slots_ssl"]["train_stores"]],
        dino=lambda w: config["encoders"]["spot"]["dino_checkpoint"] or "encoders.spot.dino_checkpoint is not set",
    output:
        ckpt=f"{paths.SPOT_SLOTS}/slot_module.pt",
        curve=f"{paths.SPOT_SLOTS}/train_curve.parquet",
    log:
        "results/logs/train_spot_slots_on_dino.log",
    benchmark:
        "results/benchmarks/train_spot_slots_on_dino.tsv"
    priority: scheduling.task_priority(config["policy"]["task"], config, threads_of("train_spot_slots"))
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("train_spot_slots")
    resources:
        **resources_of("train_spot_slots"),
    params:
        spot=config["encoders"]["spot"],
        seed=config["seed"],
    script:
        "../scripts/train_spot_slots_on_dino.py"
