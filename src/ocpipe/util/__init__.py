"""Helpers every stage shares: write-then-rename artifact writing (`atomic`), sending a job's output to its
Snakemake log file (`runlog`, used by every script in workflow/scripts/), and picking the torch device (`devices`)."""
