# Closed-loop evaluation (docs/study.md, Evaluation protocol): a sweep job per policy (all its checkpoints in one
# process, so a job's start-up, mostly imports, is paid once), the best checkpoint, stability runs (one job each),
# Table 5.5's training-time runs, training-seed runs, failure classification (docs/study.md, Failure taxonomy), and
# the study's tables and figures (docs/study.md, Tables and figures).
from ocpipe.bookkeeping import report_page
from ocpipe.study import builds, conditions, findings, registry, targets


localrules:
    best,
    findings,
    build_comparison,
    failures,
    table,
    figure,
    figures5_1_to_5_3,


# what tables and figures read from config: their rows and the settings those rows' experiments resolve to
TABLE_CFG = cfg(
    "profile",
    "replicates",
    "table_replicates",
    "replicate_seed_offset",
    "tables",
    "experiments",
    "policy",
    "encoders",
    "evaluation",
    "demos",
)


# what every evaluation job reads: its policy, the protocol, and what of the config its environment and encoder are
# built from (its camera set's cameras, its encoder's sections: job_params.evaluation_job)
EVAL_PARAMS = {
    "policy": policy_of,
    "evaluation": evaluation_job_params(),
    "cfg": lambda w: evaluation_env(policy_of(w)),
    "seed": config["seed"],
}


rule sweep:
    input:
        unpack(eval_inputs),
    output:
        episodes=f"{paths.SWEEP}.episodes.parquet",
        steps=f"{paths.SWEEP}.steps.parquet",
    log:
        "results/logs/sweep/{exp}.log",
    benchmark:
        "results/benchmarks/sweep/{exp}.tsv"
    priority: policy_priority("evaluate")
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("evaluate")
    resources:
        **resources_of("evaluate"),
    params:
        **EVAL_PARAMS,
        kind="sweep",
        epochs=lambda w: _exp.saved_epochs(policy_of(w)),
    script:
        "../scripts/sweep.py"


rule best:
    input:
        sweep=lambda w: sweep_outputs(w.exp),
        train_log=paths.TRAIN_LOG,
    output:
        json=paths.BEST,
    log:
        "results/logs/best/{exp}.log",
    benchmark:
        "results/benchmarks/best/{exp}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        alpha=config["evaluation"]["sweep_alpha"],
    script:
        "../scripts/best.py"


use rule sweep as stability with:
    input:
        unpack(eval_inputs),
        best=paths.BEST,
    output:
        episodes=f"{paths.STABILITY}.episodes.parquet",
        steps=f"{paths.STABILITY}.steps.parquet",
    log:
        "results/logs/stability/{exp}_run_{run}.log",
    benchmark:
        "results/benchmarks/stability/{exp}_run_{run}.tsv"
    wildcard_constraints:
        run=r"\d+",
    params:
        **EVAL_PARAMS,
        kind="stability",
        # `use rule ... with` keeps every keyword param it does not name: without this, a stability run would
        # evaluate each checkpoint the sweep does, not the best one alone
        epochs=None,


use rule stability as failure_run with:
    output:
        episodes=f"{paths.FAILURE_RUN}.episodes.parquet",
        steps=f"{paths.FAILURE_RUN}.steps.parquet",
    log:
        "results/logs/failure_run/{exp}.log",
    benchmark:
        "results/benchmarks/failure_run/{exp}.tsv"
    params:
        **EVAL_PARAMS,
        kind="failure_run",


use rule stability as training_time_run with:
    output:
        episodes=f"{paths.TRAINING_TIME}.episodes.parquet",
        steps=f"{paths.TRAINING_TIME}.steps.parquet",
    log:
        "results/logs/training_time_run/{exp}.log",
    benchmark:
        "results/benchmarks/training_time_run/{exp}.tsv"
    params:
        **EVAL_PARAMS,
        kind="training_time",


use rule stability as train_seed_run with:
    output:
        episodes=f"{paths.TRAIN_SEEDS}.episodes.parquet",
        steps=f"{paths.TRAIN_SEEDS}.steps.parquet",
    log:
        "results/logs/train_seed_run/{exp}.log",
    benchmark:
        "results/benchmarks/train_seed_run/{exp}.tsv"
    params:
        **EVAL_PARAMS,
        kind="train_seeds",


rule failures:
    input:
        episodes=lambda w: failure_inputs(w.exp),
    output:
        classes=paths.FAILURES,
    log:
        "results/logs/failures/{exp}.log",
    benchmark:
        "results/benchmarks/failures/{exp}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        task=lambda w: policy_of(w)["task"],
        rules=config["evaluation"]["failure_rules"],
    script:
        "../scripts/failures.py"


rule table:
    """Any of the study's tables 5.1-5.11 from its rows' experiments (config `tables`); rows whose encoder needs
    weights the config does not give say so instead of failing the table."""
    input:
        lambda w: targets.inputs(config, w.table),
        # the footer names where the rows depart from the study's recipe, which this file states
        recipe=str(conditions.STUDY_PROFILE),
    output:
        csv=report(
            f"{paths.TABLE}.csv",
            caption="../report/table.rst",
            category="Tables",
            subcategory=lambda w: report_page.table_group(w.table),
            labels=lambda w: report_page.table_label(w.table),
        ),
        md=f"{paths.TABLE}.md",
    log:
        "results/logs/tables/{table}.log",
    benchmark:
        "results/benchmarks/tables/{table}.tsv"
    wildcard_constraints:
        table="|".join(registry.TABLES),
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        cfg=TABLE_CFG,
    script:
        "../scripts/table.py"


rule findings:
    """The study's findings judged on this build's episodes: `findings` all twelve; `findings_main`,
    `findings_ablations` and `findings_stackcube` those of their target's tables (1-3, 4-10, 11-12)."""
    input:
        lambda w: targets.findings_inputs(config, w.scope),
    output:
        csv=report(
            f"{paths.TABLE_DIR}/{{scope}}.csv",
            caption="../report/findings.rst",
            category="Tables",
            subcategory=lambda w: report_page.findings_group(w.scope),
            labels=lambda w: report_page.findings_label(w.scope),
        ),
        md=f"{paths.TABLE_DIR}/{{scope}}.md",
    log:
        "results/logs/tables/{scope}.log",
    benchmark:
        "results/benchmarks/tables/{scope}.tsv"
    wildcard_constraints:
        scope="|".join(findings.SCOPES),
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        cfg=TABLE_CFG,
    script:
        "../scripts/findings.py"


rule build_comparison:
    """The findings of ``scope`` from this build's K policies and the next K (replicate_seed_offset + K), side by
    side: does any claim resolve one way in one build and the other way in the other, and does each row's mean lie
    within the other build's 95 % interval?"""
    input:
        lambda w: builds.inputs(config, w.scope),
    output:
        csv=report(
            f"{paths.TABLE_DIR}/two_builds_{{scope}}.csv",
            caption="../report/two_builds.rst",
            category="Tables",
            subcategory=lambda w: report_page.findings_group(w.scope),
            labels=lambda w: report_page.findings_label(w.scope, two_builds=True),
        ),
        rows=f"{paths.TABLE_DIR}/two_builds_{{scope}}.rows.csv",
        md=f"{paths.TABLE_DIR}/two_builds_{{scope}}.md",
    log:
        "results/logs/tables/two_builds_{scope}.log",
    benchmark:
        "results/benchmarks/tables/two_builds_{scope}.tsv"
    wildcard_constraints:
        scope="|".join(findings.SCOPES),
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        cfg=TABLE_CFG,
    script:
        "../scripts/build_comparison.py"


rule figure:
    """Figures 5.5 (SR by representation), 5.6 (failures by loss weighting) and 5.7 (StackCube funnel)."""
    input:
        lambda w: targets.inputs(config, registry.FIGURES[w.figure].table, registry.FIGURES[w.figure].needs),
    output:
        png=report(
            paths.FIGURE,
            caption="../report/figure.rst",
            category="Figures",
            subcategory=lambda w: report_page.figure_group(w.figure),
            labels=lambda w: report_page.figure_label(w.figure),
        ),
    log:
        "results/logs/figures/{figure}.log",
    benchmark:
        "results/benchmarks/figures/{figure}.tsv"
    wildcard_constraints:
        figure="|".join(registry.FIGURES),
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        cfg=TABLE_CFG,
    script:
        "../scripts/figure.py"


rule figures5_1_to_5_3:
    input:
        targets.inputs(config, registry.SPATIAL_FIGURES_TABLE, registry.SPATIAL_FIGURES_NEEDS),
    output:
        fig5_1=report(
            paths.FIGURE.format(figure="fig5_1"),
            caption="../report/fig5_1.rst",
            category="Figures",
            subcategory=report_page.figure_group("fig5_1"),
            labels=report_page.figure_label("fig5_1"),
        ),
        fig5_2=report(
            paths.FIGURE.format(figure="fig5_2"),
            caption="../report/fig5_2.rst",
            category="Figures",
            subcategory=report_page.figure_group("fig5_2"),
            labels=report_page.figure_label("fig5_2"),
        ),
        fig5_3=report(
            paths.FIGURE.format(figure="fig5_3"),
            caption="../report/fig5_3.rst",
            category="Figures",
            subcategory=report_page.figure_group("fig5_3"),
            labels=report_page.figure_label("fig5_3"),
        ),
    log:
        f"results/logs/figures/{registry.SPATIAL_FIGURES_JOB}.log",
    benchmark:
        f"results/benchmarks/figures/{registry.SPATIAL_FIGURES_JOB}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        cfg=TABLE_CFG,
    script:
        "../scripts/figures5_1_to_5_3.py"
