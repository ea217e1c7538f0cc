import json

from ocpipe.features import diagnostics
from ocpipe.util import runlog
from ocpipe.util.atomic import write_json

w = snakemake.wildcards
with runlog.to_file(snakemake.log[0]):
    # decomposition is scored on frames the encoder never trained on: a training store's held-out tail
    in_training = f"{w.task}_{w.cams}_{w.res}" in snakemake.params.train_stores
    report = diagnostics.diagnostics(snakemake.input.frames, snakemake.input.features,
                                     snakemake.params.holdout if in_training else None,
                                     probe_holdout=snakemake.params.probe_holdout,
                                     probe_mlp_epochs=snakemake.params.probe_mlp_epochs, seed=snakemake.params.seed)
    write_json(snakemake.output.json, report)
    print(json.dumps(report, indent=2))
