"""The study's results (the table and figure rules of workflow/rules/evaluation.smk, and the group targets in the
Snakefile): what a table reads per row and how (`inputs`: stability runs, failure classes, training logs, ...),
which experiments and files each table and figure reads (`targets`, used by the rule files), the tables
and figures the study reports (`registry`), building the tables (`tables`), drawing the figures (`figures`),
assembling both from a run's files (`report`, rules `table`, `figure`, `figures5_1_to_5_3`), the findings and the
claims they test (`findings`, `claims`), two builds side by side (`builds`), the levers table (`levers`), the study's
recipe against the default profile (`conditions`), and the headline summary of a results folder (`summary`,
`ocpipe summary`). Statistics live in `ocpipe.stats`, failure classification in `ocpipe.evaluation.taxonomy`, a
run's cost and progress in `ocpipe.bookkeeping`."""
