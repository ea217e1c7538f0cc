# Expert demonstrations: motion-planning shards on disjoint seed ranges merged into one ManiSkill h5+json per
# task, or official demo files imported from paths in config (demos.source).

if config["demos"]["source"] == "motionplanning":

    rule demos_shard:
        output:
            h5=f"{paths.DEMO_SHARD}.h5",
            json=f"{paths.DEMO_SHARD}.json",
            report=f"{paths.DEMO_SHARD}.report.json",
        log:
            "results/logs/demos_shard/{task}_shard{shard}.log",
        benchmark:
            "results/benchmarks/demos_shard/{task}_shard{shard}.tsv"
        priority: store_priority("demos")
        conda:
            "../envs/ocpipe.yaml"
        threads: threads_of("demos")
        resources:
            **resources_of("demos"),
        params:
            cfg=demo_params(),
        script:
            "../scripts/demos_shard.py"

    rule demos_merge:
        input:
            h5=expand(f"{paths.DEMO_SHARD}.h5", shard=range(config["demos"]["shards"]), allow_missing=True),
            reports=expand(
                f"{paths.DEMO_SHARD}.report.json", shard=range(config["demos"]["shards"]), allow_missing=True
            ),
        output:
            h5=f"{paths.DEMOS}.h5",
            json=f"{paths.DEMOS}.json",
            report=f"{paths.DEMOS}.report.json",
        log:
            "results/logs/demos_merge/{task}.log",
        benchmark:
            "results/benchmarks/demos_merge/{task}.tsv"
        conda:
            "../envs/ocpipe.yaml"
        threads: threads_of("light")
        resources:
            **resources_of("light"),
        script:
            "../scripts/demos_merge.py"

else:

    rule demos_import:
        input:
            h5=lambda w: config["demos"]["import"][w.task]["h5"],
            json=lambda w: config["demos"]["import"][w.task]["json"],
        output:
            h5=f"{paths.DEMOS}.h5",
            json=f"{paths.DEMOS}.json",
            report=f"{paths.DEMOS}.report.json",
        log:
            "results/logs/demos_import/{task}.log",
        benchmark:
            "results/benchmarks/demos_import/{task}.tsv"
        conda:
            "../envs/ocpipe.yaml"
        threads: threads_of("light")
        resources:
            **resources_of("light"),
        params:
            cfg=demo_params(),
        script:
            "../scripts/demos_import.py"
