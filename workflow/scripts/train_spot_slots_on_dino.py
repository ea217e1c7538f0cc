import polars as pl
import torch

from ocpipe.encoders import checkpoints, dinosaur
from ocpipe.frames.store import open_store
from ocpipe.util import runlog
from ocpipe.util.atomic import atomic_path
from ocpipe.util.devices import pick_device

with runlog.to_file(snakemake.log[0]):
    spot = snakemake.params.spot
    vit = checkpoints.load_dino_vit(snakemake.input.dino, config_key="encoders.spot.dino_checkpoint")
    images = torch.cat([dinosaur.frames_sample(open_store(p), spot["train_frames"]) for p in snakemake.input.stores])
    sa, curve = dinosaur.train_slot_module(vit, images, spot["image_size"], spot["train_steps"], spot["batch_size"],
                                           spot["lr"], snakemake.params.seed, threads=snakemake.threads,
                                           device=pick_device(spot["device"]))
    with atomic_path(snakemake.output.ckpt) as tmp:
        dinosaur.save_slot_module(sa, tmp, {"dino_checkpoint": str(snakemake.input.dino)})
    with atomic_path(snakemake.output.curve) as tmp:
        pl.DataFrame(curve).write_parquet(tmp)
