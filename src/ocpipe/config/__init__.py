"""Configuration: loading and validating config/config.yaml (plus overrides) against
workflow/schemas/config.schema.yaml (`validate`, raising `errors.ConfigError`), named experiments resolved from the
base `policy` section (`experiments`), what each workflow job reads of the config, passed as its params
(`job_params`), and the generated reference config/README.md (`docs`). The Snakefile
validates every run's config with it, the rule files (workflow/rules/common.smk) resolve experiments with it, and
`ocpipe check-config` / `ocpipe config-docs` wrap it."""
