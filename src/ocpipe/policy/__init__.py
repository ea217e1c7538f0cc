"""The Autoregressive Multimodal Sequence Policy (SPEC section 7): model, data windows, losses and training."""
