"""The frames stage (workflow/rules/frames.smk): env-state-aligned replay of every demo (`replay`), rendered with
the study's cameras into shard stores (`render`, rule `frames_shard`), merged into one Zarr frames store per
(task, camera set, resolution) whose contract `store` writes and checks (`frames_merge`, `ocpipe check-store`),
and its summary and contact sheet (`report`, rule `frames_report`)."""
