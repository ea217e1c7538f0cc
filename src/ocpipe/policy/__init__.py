"""The Autoregressive Multimodal Sequence Policy (docs/study.md, Policy): model, data windows, losses, training.
The policy stage (workflow/rules/policy.smk, rule `train`) runs `training.train` once per experiment; an
experiment's settings arrive as a config dict and are read as `settings.PolicySettings`."""
