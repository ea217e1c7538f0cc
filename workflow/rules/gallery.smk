# The gallery (docs/pipeline.md, Gallery): for each row of the main job's and StackCube's tables and each failure
# class among its episodes, a few evaluated episodes replayed as videos (a viewer camera beside the views the policy
# saw) and a contact sheet per class, one job per experiment; `snakemake gallery` builds them all.
rule gallery_experiment:
    """One experiment's gallery: its picked episodes (config `gallery`) as videos, a contact sheet per failure class,
    and episodes.csv naming what was picked."""
    input:
        unpack(gallery_inputs),
    output:
        videos=report(
            directory(f"{paths.GALLERY}/videos"),
            # each video's page (ocpipe.util.video_page): the report offers an MP4 or a GIF only as a download
            patterns=["{cls}-{replicate}-{seed}.html"],
            caption="../report/gallery_video.rst",
            category="Gallery",
            subcategory=gallery_group,
            labels=lambda w: gallery_selection.video_label(w.cls, w.replicate, w.seed),
        ),
        sheets=report(
            directory(f"{paths.GALLERY}/sheets"),
            patterns=["{cls}.png"],
            caption="../report/gallery_sheet.rst",
            category="Gallery",
            subcategory=gallery_group,
            labels=lambda w: gallery_selection.sheet_label(w.cls),
        ),
        manifest=f"{paths.GALLERY}/episodes.csv",
    log:
        "results/logs/gallery/{exp}.log",
    benchmark:
        "results/benchmarks/gallery/{exp}.tsv"
    wildcard_constraints:
        exp="|".join(GALLERY_ROWS) or "no_gallery_row",
    conda:
        "../envs/ocpipe.yaml"
    threads: threads_of("evaluate")
    resources:
        **resources_of("evaluate"),
    params:
        policy=policy_of,
        cfg=lambda w: evaluation_env(policy_of(w)),
        gallery=config["gallery"],
        near_miss_m=config["evaluation"]["failure_rules"]["near_miss_m"],
        seed=config["seed"],
        tables=lambda w: GALLERY_ROWS[w.exp],
        runs=lambda w: gallery_runs(w.exp),
    script:
        "../scripts/gallery.py"
