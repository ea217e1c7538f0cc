"""Frozen visual encoders: the offline slots_ssl default, SPOT and DINO."""
