from ocpipe.demos import merge
from ocpipe.util import runlog
from ocpipe.util.atomic import write_json

with runlog.to_file(snakemake.log[0]):
    report = merge.import_official(snakemake.input.h5, snakemake.input.json, snakemake.output.h5,
                                   snakemake.params.cfg, snakemake.wildcards.task)
    write_json(snakemake.output.report, report)
