from ocpipe.demos import motion_planning
from ocpipe.util import runlog
from ocpipe.util.atomic import write_json

with runlog.to_file(snakemake.log[0]):
    report = motion_planning.generate_shard(snakemake.wildcards.task, snakemake.params.cfg,
                                            int(snakemake.wildcards.shard), snakemake.output.h5)
    write_json(snakemake.output.report, report)
