"""Frozen visual encoders: the offline slots_ssl default, SPOT and DINO, and the privileged-state control
(`registry` builds one by name for the features and evaluation stages). The encoders stage
(workflow/rules/encoders.smk) trains slots_ssl (`training`, rule `train_slots_ssl`; scored with `decomposition`
and `slot_metrics`) and, with only DINO weights given, SPOT's slot module (`dinosaur`, rule
`train_spot_slots_on_dino`)."""
