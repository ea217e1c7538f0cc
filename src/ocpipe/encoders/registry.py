"""Encoder names the workflow knows, and how each is built for one frames store."""

from __future__ import annotations

from pathlib import Path

from ..frames.store import open_store

SLOT_ENCODERS = ("slots_ssl", "spot")
DINO_READOUTS = ("cls", "grid4", "dense")
# every encoder a features store can be made with ('state': the privileged-state control's object pose)
ENCODERS = SLOT_ENCODERS + tuple(f"dino_{r}" for r in DINO_READOUTS) + ("state",)
# the sections of config `encoders` that build() reads for each encoder: none for slots_ssl (its weights are the
# workflow's own checkpoint, an input file, whose settings train_slots_ssl reads), SPOT only its own (it names the
# DINO weights it loads itself), the DINO readouts `dino`, the state control `state`. A job building an encoder is
# handed just these (ocpipe.config.job_params), so a change to another encoder's settings does not rerun it.
CONFIG_SECTIONS = {"slots_ssl": (), "spot": ("spot",), **{f"dino_{r}": ("dino",) for r in DINO_READOUTS},
                   "state": ("state",)}


def build(name: str, encoders_cfg: dict, frames_path: str | Path, trained_checkpoint: str | Path | None = None,
          cameras: list[int] | None = None):
    """A frozen encoder for the frames store at ``frames_path``; ``cameras`` (indices into the store's cameras):
    it encodes images of only these, in this order (default: all of the store's).

    ``trained_checkpoint``: a checkpoint the workflow produced (slots_ssl, or SPOT's slot module trained on DINO);
    user-given weights come from ``encoders_cfg`` (of it, only the sections CONFIG_SECTIONS names) and a missing file
    names its config key."""
    if name not in ENCODERS:
        raise ValueError(f"unknown encoder {name!r}; known: {', '.join(ENCODERS)}")
    if name == "state":
        from .state import StateEncoder

        return StateEncoder(**encoders_cfg.get("state", {}))
    store = open_store(frames_path)
    if name == "slots_ssl":
        from .frozen_ssl import FrozenSSLSlots

        if trained_checkpoint is None:
            raise ValueError("slots_ssl needs its trained checkpoint (results/encoders/slots_ssl/model.pt)")
        pick = slice(None) if cameras is None else list(cameras)
        return FrozenSSLSlots(trained_checkpoint, store["cam_intrinsic"][...][pick],
                              store["cam_extrinsic"][...][pick], store.attrs["resolution"])
    from .frozen_vit import FrozenDINO, FrozenSPOT

    if name == "spot":
        return FrozenSPOT.from_config(encoders_cfg["spot"], trained_checkpoint)
    return FrozenDINO.from_config(encoders_cfg["dino"], name.removeprefix("dino_"))


def tokens_per_camera(name: str, encoders_cfg: dict) -> int:
    """Visual tokens one camera frame becomes (slots, or DINO's CLS / 4x4 / 14x14 readout at 224 px)."""
    if name == "slots_ssl":
        return int(encoders_cfg["slots_ssl"]["num_slots"])
    if name == "spot":
        return 7
    if name == "state":
        return 1
    patches = encoders_cfg["dino"]["image_size"] // 16
    return {"dino_cls": 1, "dino_grid4": 16, "dino_dense": patches * patches}[name]
