"""The evaluation stage (workflow/rules/evaluation.smk): closed-loop rollouts of a policy checkpoint in the
simulator (`closed_loop`), what each evaluation job runs and the best checkpoint of a sweep (`jobs`, rules
`sweep`, `stability`, `failure_run`, `training_time_run`, `train_seed_run` and `best`), and the failure taxonomy
on per-step logs (`taxonomy`, rule `failures`)."""
