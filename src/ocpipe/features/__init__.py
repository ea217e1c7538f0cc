"""The features stage (workflow/rules/features.smk): every frame of a frames store encoded once by a frozen
encoder into a features store (`encode`, rule `features`), the store's diagnostics and position probes
(`diagnostics` and `probes`, rule `features_diagnostics`) and per-slot attention-map figures (`attention`, rule
`attention_maps`)."""
