"""Helpers every stage shares: write-then-rename artifact writing (`atomic`), sending a job's output to its
Snakemake log file (`runlog`, used by every script in workflow/scripts/), picking the torch device (`devices`), and
an MP4 as a page Snakemake's HTML report can play (`video_page`)."""
