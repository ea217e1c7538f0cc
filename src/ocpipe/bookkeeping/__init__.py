"""What a run of the workflow cost and how far it has got, read from Snakemake's benchmark files and logs:
`compute` (the compute table), `progress` (jobs done and time left), `record` (a finished run copied into docs),
`report_page` (what Snakemake's HTML report shows of a run: its landing page, captions and menu)."""
