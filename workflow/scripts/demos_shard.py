from ocpipe import demos, runlog
from ocpipe.atomic import write_json

with runlog.to_file(snakemake.log[0]):
    report = demos.generate_shard(snakemake.wildcards.task, snakemake.params.cfg, int(snakemake.wildcards.shard),
                                  snakemake.output.h5)
    write_json(snakemake.output.report, report)
