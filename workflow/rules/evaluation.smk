# Closed-loop evaluation (SPEC section 8): a sweep job per (experiment, checkpoint), the best checkpoint, stability
# runs (one job each), failure classification (SPEC section 9), and Table 5.1 / 5.2 with figures 5.1-5.3.
from types import SimpleNamespace


localrules:
    best,
    failures,
    table5_1,
    table5_2,
    figures5_1_to_5_3,


# the config sections an evaluation job's environment and encoder are built from
EVAL_ENV_CFG = cfg("sim", "cameras", "camera_approx", "frames", "encoders")


def eval_inputs(w):
    p = policy_of(w)
    return {
        "checkpoints": f"results/runs/{w.exp}/checkpoints",
        "frames": f"results/frames/{_exp.frames_store(p)}.zarr",
        "encoder": encoder_checkpoint(SimpleNamespace(encoder=p["encoder"])),
    }


def sweep_outputs(exp):
    return [f"results/runs/{exp}/sweep/epoch_{e:04d}.episodes.parquet"
            for e in _exp.saved_epochs(_exp.resolve(config, exp))]


def stability_outputs(exp):
    return [f"results/runs/{exp}/stability/run_{r}.episodes.parquet"
            for r in range(config["evaluation"]["stability_runs"])]


def failure_inputs(exp):
    """Episodes the taxonomy classifies: a dedicated run, or (failure_episodes: 0) the stability runs."""
    if config["evaluation"]["failure_episodes"]:
        return [f"results/runs/{exp}/failure_run.episodes.parquet"]
    return stability_outputs(exp)


def table_rows(table):
    return config["tables"][table]


rule sweep:
    input:
        unpack(eval_inputs),
    output:
        episodes="results/runs/{exp}/sweep/epoch_{epoch}.episodes.parquet",
        steps="results/runs/{exp}/sweep/epoch_{epoch}.steps.parquet",
    wildcard_constraints:
        epoch=r"\d{4}",
    params:
        kind="sweep",
        policy=policy_of,
        evaluation=config["evaluation"],
        cfg=EVAL_ENV_CFG,
        seed=config["seed"],
    log:
        "results/logs/sweep/{exp}_epoch_{epoch}.log",
    benchmark:
        "results/benchmarks/sweep/{exp}_epoch_{epoch}.tsv"
    threads: config["compute"]["evaluate"]
    resources:
        mem_mb=3000,
    conda:
        "../envs/ocpipe.yaml"
    script:
        "../scripts/evaluate.py"


rule best:
    input:
        sweep=lambda w: sweep_outputs(w.exp),
    output:
        json="results/runs/{exp}/best.json",
    log:
        "results/logs/best/{exp}.log",
    benchmark:
        "results/benchmarks/best/{exp}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    script:
        "../scripts/best.py"


rule stability:
    input:
        unpack(eval_inputs),
        best="results/runs/{exp}/best.json",
    output:
        episodes="results/runs/{exp}/stability/run_{run}.episodes.parquet",
        steps="results/runs/{exp}/stability/run_{run}.steps.parquet",
    wildcard_constraints:
        run=r"\d+",
    params:
        kind="stability",
        policy=policy_of,
        evaluation=config["evaluation"],
        cfg=EVAL_ENV_CFG,
        seed=config["seed"],
    log:
        "results/logs/stability/{exp}_run_{run}.log",
    benchmark:
        "results/benchmarks/stability/{exp}_run_{run}.tsv"
    threads: config["compute"]["evaluate"]
    resources:
        mem_mb=3000,
    conda:
        "../envs/ocpipe.yaml"
    script:
        "../scripts/evaluate.py"


rule failure_run:
    input:
        unpack(eval_inputs),
        best="results/runs/{exp}/best.json",
    output:
        episodes="results/runs/{exp}/failure_run.episodes.parquet",
        steps="results/runs/{exp}/failure_run.steps.parquet",
    params:
        kind="failure_run",
        policy=policy_of,
        evaluation=config["evaluation"],
        cfg=EVAL_ENV_CFG,
        seed=config["seed"],
    log:
        "results/logs/failure_run/{exp}.log",
    benchmark:
        "results/benchmarks/failure_run/{exp}.tsv"
    threads: config["compute"]["evaluate"]
    resources:
        mem_mb=3000,
    conda:
        "../envs/ocpipe.yaml"
    script:
        "../scripts/evaluate.py"


rule failures:
    input:
        episodes=lambda w: failure_inputs(w.exp),
    output:
        classes="results/runs/{exp}/failures.parquet",
    params:
        task=lambda w: policy_of(w)["task"],
        rules=config["evaluation"]["failure_rules"],
    log:
        "results/logs/failures/{exp}.log",
    benchmark:
        "results/benchmarks/failures/{exp}.tsv"
    conda:
        "../envs/ocpipe.yaml"
    script:
        "../scripts/failures.py"


rule table5_1:
    input:
        runs=[f for e in table_rows("table5_1").values() for f in stability_outputs(e)],
    output:
        csv=report("results/tables/table5_1.csv", category="Tables", labels={"table": "5.1 spatial grounding"}),
        md="results/tables/table5_1.md",
    params:
        rows=table_rows("table5_1"),
        n_runs=config["evaluation"]["stability_runs"],
    log:
        "results/logs/tables/table5_1.log",
    benchmark:
        "results/benchmarks/tables/table5_1.tsv"
    conda:
        "../envs/ocpipe.yaml"
    script:
        "../scripts/table5_1.py"


rule table5_2:
    input:
        classes=[f"results/runs/{e}/failures.parquet" for e in table_rows("table5_1").values()],
    output:
        csv=report("results/tables/table5_2.csv", category="Tables", labels={"table": "5.2 failure distribution"}),
        md="results/tables/table5_2.md",
    params:
        rows=table_rows("table5_1"),
    log:
        "results/logs/tables/table5_2.log",
    benchmark:
        "results/benchmarks/tables/table5_2.tsv"
    conda:
        "../envs/ocpipe.yaml"
    script:
        "../scripts/table5_2.py"


rule figures5_1_to_5_3:
    input:
        train=[f"results/runs/{e}/train_log.parquet" for e in table_rows("table5_1").values()],
        sweeps=[f for e in table_rows("table5_1").values() for f in sweep_outputs(e)],
        runs=[f for e in table_rows("table5_1").values() for f in stability_outputs(e)],
        classes=[f"results/runs/{e}/failures.parquet" for e in table_rows("table5_1").values()],
    output:
        fig5_1=report("results/figures/fig5_1.png", category="Figures", labels={"figure": "5.1 training loss and evaluation reward"}),
        fig5_2=report("results/figures/fig5_2.png", category="Figures", labels={"figure": "5.2 episode length"}),
        fig5_3=report("results/figures/fig5_3.png", category="Figures", labels={"figure": "5.3 failure counts"}),
    params:
        rows=table_rows("table5_1"),
    log:
        "results/logs/figures/fig5_1_to_5_3.log",
    benchmark:
        "results/benchmarks/figures/fig5_1_to_5_3.tsv"
    conda:
        "../envs/ocpipe.yaml"
    script:
        "../scripts/figures5_1_to_5_3.py"
