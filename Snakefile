# ocpipe: object-centric behavior cloning on ManiSkill3, from expert demos to the study's tables.
# Parameters: config/config.yaml (CPU default profile), validated against workflow/schemas/config.schema.yaml.
import sys
from pathlib import Path

from ocpipe.config import ConfigError, validate

configfile: Path(workflow.basedir) / "config" / "config.yaml"

try:
    validate(config)
except ConfigError as err:
    sys.exit(f"ocpipe: {err}")


include: "workflow/rules/common.smk"
include: "workflow/rules/demos.smk"
include: "workflow/rules/frames.smk"
include: "workflow/rules/encoders.smk"
include: "workflow/rules/features.smk"


rule all:
    default_target: True
    input:
        frames_targets(),
        features_targets(),
