"""The study's results (the table, figure and failures rules of workflow/rules/evaluation.smk, and the group
targets in the Snakefile): which experiments and files each table and figure reads (`targets`, used by the rule
files), building the tables (`tables`), drawing the figures (`figures`), assembling both from a run's files
(`report`, rules `table`, `figure`, `figures5_1_to_5_3`, `failures`), and the headline summary of a results
folder (`summary`, `ocpipe summary`)."""
