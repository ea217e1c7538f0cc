# rule sweep, and the rules derived from it (stability, failure_run, training_time_run, train_seed_run): one
# evaluation job
from ocpipe.evaluation import jobs
from ocpipe.util import runlog

w, p = snakemake.wildcards, snakemake.params
config = {**p.cfg, "evaluation": p.evaluation}
with runlog.to_file(snakemake.log[0]):
    episodes = jobs.run_job(
        p.kind, w.exp, config, snakemake.input.checkpoints, snakemake.input.frames, snakemake.input.encoder,
        snakemake.output.episodes, snakemake.output.steps, p.seed, run=int(w.get("run", 0)),
        best_json=snakemake.input.get("best"), epochs=p.get("epochs"),
        threads=snakemake.threads, policy=p.policy)
    print(episodes)
