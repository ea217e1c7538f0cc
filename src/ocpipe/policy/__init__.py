"""The Autoregressive Multimodal Sequence Policy (docs/study.md, Policy): model, data windows, losses, training."""
