"""ocpipe: reproducible object-centric behavior-cloning experiments on ManiSkill3."""

__version__ = "0.1.0"
