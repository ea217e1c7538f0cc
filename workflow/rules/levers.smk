# Levers (config `levers.sets`): candidate changes to the recipe, each trained as `levers.replicates` policies and
# evaluated on the validation pool, never on a table's seeds; the levers table sets each beside its experiment's
# baseline.


use rule train as lever_train with:
    input:
        unpack(lever_train_inputs),
    output:
        checkpoints=directory(f"{paths.LEVER}/checkpoints"),
        log=f"{paths.LEVER}/train_log.parquet",
    log:
        "results/logs/lever_train/{lever}.log",
    benchmark:
        "results/benchmarks/lever_train/{lever}.tsv"
    params:
        policy=lever_of,
        seed=training_seed,
        camera_approx=lambda w: training_camera_approx(lever_of(w)),


rule lever_eval:
    input:
        unpack(lever_eval_inputs),
    output:
        episodes=f"{paths.LEVER_EVAL}.episodes.parquet",
        steps=f"{paths.LEVER_EVAL}.steps.parquet",
    log:
        "results/logs/lever_eval/{lever}.log",
    benchmark:
        "results/benchmarks/lever_eval/{lever}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("evaluate")
    resources:
        **resources_of("evaluate"),
    params:
        policy=lever_of,
        evaluation=evaluation_job_params(),
        cfg=lambda w: evaluation_env(lever_of(w)),
        seed=config["seed"],
        episodes=config["levers"]["episodes"],
    script:
        "../scripts/lever_eval.py"


rule levers:
    """The levers table: results/tables/levers.{csv,md}."""
    input:
        [f for policies in LEVER_FILES.values() for files in policies for f in files],
    output:
        csv=report(
            f"{paths.TABLE_DIR}/levers.csv",
            caption="../report/levers.rst",
            category="Tables",
            subcategory=report_page.LEVERS,
            labels={"table": "levers on the validation pool"},
        ),
        md=f"{paths.TABLE_DIR}/levers.md",
    log:
        "results/logs/levers.log",
    benchmark:
        "results/benchmarks/levers.tsv"
    localrule: True
    conda:
        "../envs/ocpipe.yaml"
    params:
        cfg=cfg("profile", "levers"),
        files=LEVER_FILES,
    script:
        "../scripts/levers.py"
