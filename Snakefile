# ocpipe: object-centric behavior cloning on ManiSkill3, from expert demos to the study's tables.
# Parameters: config/config.yaml (CPU default profile), validated against workflow/schemas/config.schema.yaml.
import sys
from pathlib import Path

from ocpipe.bookkeeping import report_page
from ocpipe.config.errors import ConfigError
from ocpipe.config.validate import validate
from ocpipe.study import registry
from ocpipe.study.findings import check_config


configfile: Path(workflow.current_basedir) / "config" / "config.yaml"


try:
    validate(config)
    check_config(config)  # tables the registry defines, holding every experiment the findings compare
except ConfigError as err:
    sys.exit(f"ocpipe: {err}")


# `snakemake --report` opens on this page: the findings, Table 5.1, the profile and the commit. Snakemake renders it
# with Jinja, which sees the config but no file, then with docutils in this process: the directives registered here
# read the run's tables and the checkout's commit when the report is built (ocpipe.bookkeeping.report_page).
report_page.register(workflow.basedir)


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/demos.smk"
include: "workflow/rules/frames.smk"
include: "workflow/rules/encoders.smk"
include: "workflow/rules/features.smk"
include: "workflow/rules/policy.smk"
include: "workflow/rules/evaluation.smk"
include: "workflow/rules/gallery.smk"
include: "workflow/rules/levers.smk"


# when a run ends, its jobs' CPU as the kernel counted it (keep_run_cpu, common.smk)
onsuccess:
    keep_run_cpu(log)


onerror:
    keep_run_cpu(log)


rule spatial_grounding:
    """The main job: Tables 5.1 and 5.2, the findings they cover (1-3) and figures 5.1-5.3 (Pure Visual / 2D-Spatial-Proj / Explicit-3D-GT and the
    privileged-state control), with the diagnostics and position probes of the visual policies' features store."""
    input:
        expand(f"{paths.TABLE}.csv", table=registry.tables_in("main")),
        f"{paths.TABLE_DIR}/findings_main.csv",
        expand(paths.FIGURE, figure=registry.SPATIAL_FIGURES),
        [paths.features_diagnostics(s) for s in targets.image_stores(config, registry.SPATIAL_FIGURES_TABLE)],
        built_gallery("main"),  # none on a first build; kept up to date, and in its report, once drawn


rule encodings:
    """Frames stores of the configured tasks (config `tasks`), their features, diagnostics and attention maps."""
    input:
        frames_targets(),
        features_targets(),


rule ablations:
    """Tables 5.3-5.9, the findings they cover (4-10) and figures 5.5-5.6 (PickCube)."""
    input:
        expand(f"{paths.TABLE}.csv", table=registry.tables_in("ablations")),
        f"{paths.TABLE_DIR}/findings_ablations.csv",
        expand(paths.FIGURE, figure=registry.figures_in("ablations")),


rule stackcube:
    """Tables 5.10-5.11, the findings they cover (11-12) and figure 5.7 (StackCube native vs aligned, failures with
    Grasp No Stack, funnel)."""
    input:
        expand(f"{paths.TABLE}.csv", table=registry.tables_in("stackcube")),
        f"{paths.TABLE_DIR}/findings_stackcube.csv",
        expand(paths.FIGURE, figure=registry.figures_in("stackcube")),
        built_gallery("stackcube"),


rule gallery:
    """Evaluated episodes to watch, after the main job: for each row of Tables 5.1/5.2 and each failure class among
    its episodes, `gallery.episodes_per_class` episodes drawn as videos and a contact sheet (results/gallery/{exp}/).
    """
    input:
        gallery_targets("main"),


rule gallery_stackcube:
    """The same for the rows of Tables 5.10/5.11, after `stackcube`."""
    input:
        gallery_targets("stackcube"),


rule two_builds:
    """The main job's and StackCube's findings (1-3, 11-12) from two independent builds of K policies each (config
    `replicate_seed_offset` and offset + K), side by side (results/tables/two_builds_*.md)."""
    input:
        expand(f"{paths.TABLE_DIR}/two_builds_{{scope}}.md", scope=("findings_main", "findings_stackcube")),


rule compute:
    """Where the whole study's time went (results/tables/compute.{csv,md}), from every rule's benchmark file; it
    runs last, after everything else `all` builds."""
    input:
        rules.encodings.input,
        experiment_encoding_targets(),
        rules.spatial_grounding.input,
        rules.ablations.input,
        rules.stackcube.input,
        f"{paths.TABLE_DIR}/findings.csv",
        rules.gallery.input,
        rules.gallery_stackcube.input,
    output:
        csv=report(
            f"{paths.TABLE_DIR}/compute.csv",
            caption="workflow/report/compute.rst",
            category="Tables",
            subcategory=report_page.WHOLE_STUDY,
            labels={"table": "compute: where the run's time went"},
        ),
        md=f"{paths.TABLE_DIR}/compute.md",
    log:
        "results/logs/tables/compute.log",
    benchmark:
        "results/benchmarks/compute.tsv"
    conda:
        "workflow/envs/ocpipe.yaml"
    threads: threads_of("light")
    resources:
        **resources_of("light"),
    params:
        cfg=TABLE_CFG,
        benchmarks="results/benchmarks",
    script:
        "workflow/scripts/compute.py"


rule all:
    """Everything the study reports, with the attention maps (appendix E) of every store an experiment uses, the
    gallery of evaluated episodes, and the compute table of the run."""
    default_target: True
    input:
        rules.compute.input,
        rules.compute.output.csv,
