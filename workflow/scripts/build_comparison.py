from ocpipe.study import builds
from ocpipe.util import runlog

with runlog.to_file(snakemake.log[0]):
    o = snakemake.output
    agree, within = builds.write(snakemake.params.cfg, snakemake.wildcards.scope, o.csv, o.rows, o.md)
    print(f"no claim resolved both ways: {agree}; every mean within the other build's interval: {within}")
