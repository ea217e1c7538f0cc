# rule lever_eval: a lever's last checkpoint on the validation pool
from ocpipe.evaluation import jobs
from ocpipe.util import runlog

w, p = snakemake.wildcards, snakemake.params
config = {**p.cfg, "evaluation": p.evaluation}
with runlog.to_file(snakemake.log[0]):
    print(jobs.run_job("validation", w.lever, config, snakemake.input.checkpoints, snakemake.input.frames,
                       snakemake.input.encoder, snakemake.output.episodes, snakemake.output.steps, p.seed,
                       epochs=[p.policy["epochs"]], threads=snakemake.threads, policy=p.policy,
                       validation_episodes=p.episodes))
