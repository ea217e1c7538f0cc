import json

from ocpipe.features import diagnostics
from ocpipe.util import runlog
from ocpipe.util.atomic import write_json

with runlog.to_file(snakemake.log[0]):
    # decomposition is scored on frames the encoder never trained on: a training store's held-out tail (None:
    # every episode of a store it never trained on)
    report = diagnostics.diagnostics(snakemake.input.frames, snakemake.input.features, snakemake.params.holdout,
                                     probe_holdout=snakemake.params.probe_holdout,
                                     probe_mlp_epochs=snakemake.params.probe_mlp_epochs, seed=snakemake.params.seed)
    write_json(snakemake.output.json, report)
    print(json.dumps(report, indent=2))
