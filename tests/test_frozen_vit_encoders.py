"""SPOT and DINO features through the registry, on ViT-B/16 checkpoints written here in the official layouts."""

import numpy as np
import pytest
import torch
from test_frames_store import write_shard
from tolerances import EPS32, reduction_atol

from ocpipe.encoders import checkpoints as CK
from ocpipe.encoders import dinosaur, registry
from ocpipe.encoders.slot_attention import SlotAttention
from ocpipe.encoders.vit import ViT
from ocpipe.features import encode


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    d = tmp_path_factory.mktemp("weights")
    torch.manual_seed(0)
    vit, sa = ViT().eval(), SlotAttention().eval()
    CK.write_dino_layout(vit, d / "dino_vitbase16_pretrain.pth")
    CK.write_spot_layout(vit, sa, d / "checkpoint.pt.tar")
    return d


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    path = tmp_path_factory.mktemp("frames") / "f.zarr"
    write_shard(path, [3], 0)  # 3 frames, 2 cameras, 32 px
    return path


def cfg(weights, **spot):
    return {"spot": {"checkpoint": None, "dino_checkpoint": None, "image_size": 224, **spot},
            "dino": {"checkpoint": str(weights / "dino_vitbase16_pretrain.pth"), "image_size": 224}}


@pytest.mark.parametrize("readout, tokens", [("cls", 1), ("grid4", 16), ("dense", 196)])
def test_dino_readouts(weights, frames, tmp_path, readout, tokens):
    enc = registry.build(f"dino_{readout}", cfg(weights), frames)
    encode.encode_store(enc, frames, tmp_path / "f.zarr", batch_size=2, chunk_frames=2, progress=False)
    out = encode.open_features(tmp_path / "f.zarr")
    assert out["tokens"].shape == (3, 2, tokens, 768) and "masks" not in out
    assert out.attrs["checkpoint_sha256"] == encode.sha256(weights / "dino_vitbase16_pretrain.pth")
    assert np.isfinite(out["tokens"][...].astype(np.float32)).all()


def test_spot_from_its_checkpoint_gives_seven_slots_with_masks(weights, frames, tmp_path):
    enc = registry.build("spot", cfg(weights, checkpoint=str(weights / "checkpoint.pt.tar")), frames)
    encode.encode_store(enc, frames, tmp_path / "s.zarr", batch_size=3, chunk_frames=2, progress=False)
    out = encode.open_features(tmp_path / "s.zarr")
    assert out["tokens"].shape == (3, 2, 7, 256) and out["masks"].shape == (3, 2, 7, 14, 14)
    # derived: the store holds float16 masks: each of the 7 rounds by <= 2**-11 of itself (2**-25 if subnormal), so
    # their sum by <= 2**-11 + 7 * 2**-25; the float32 softmax's and this sum's round-off add reduction_atol
    np.testing.assert_allclose(out["masks"][...].astype(np.float32).sum(2), 1.0, rtol=0,
                               atol=2**-11 + 7 * 2**-25 + reduction_atol(7, 1.0, depth=2, eps=EPS32))


def test_missing_weights_name_the_config_key(weights, frames):
    c = cfg(weights)
    with pytest.raises(FileNotFoundError, match="encoders.spot.checkpoint.*encoders.spot.dino_checkpoint"):
        registry.build("spot", c, frames)
    c["dino"]["checkpoint"] = None
    with pytest.raises(FileNotFoundError, match="encoders.dino.checkpoint"):
        registry.build("dino_cls", c, frames)
    with pytest.raises(ValueError, match="unknown encoder 'clip'"):
        registry.build("clip", c, frames)


def test_slot_module_trained_on_frozen_dino_loads_as_spot(weights, frames, tmp_path):
    from ocpipe.frames.store import open_store

    vit = CK.load_dino_vit(weights / "dino_vitbase16_pretrain.pth")
    images = dinosaur.frames_sample(open_store(frames), 3)
    before = [p.clone() for p in vit.parameters()][:3]
    sa, curve = dinosaur.train_slot_module(vit, images, 64, steps=2, batch_size=2, lr=1e-3, seed=0, progress=False)
    # exact: the backbone is frozen, so its parameters are the very values cloned before training
    assert len(curve) == 2 and all(torch.equal(a, b) for a, b in zip(before, vit.parameters()))
    dinosaur.save_slot_module(sa, tmp_path / "slot_module.pt", {})
    enc = registry.build("spot", cfg(weights, dino_checkpoint=str(weights / "dino_vitbase16_pretrain.pth")), frames,
                         tmp_path / "slot_module.pt")
    tokens, masks = enc.encode(torch.from_numpy(open_store(frames)["rgb"][:1]))
    assert tokens.shape == (1, 2, 7, 256) and masks.shape == (1, 2, 7, 14, 14)
