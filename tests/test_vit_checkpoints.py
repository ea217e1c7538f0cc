"""ViT, Slot Attention and the official DINO / SPOT checkpoint layouts, on checkpoints written here."""

import pytest
import torch

from ocpipe.encoders import checkpoints as CK
from ocpipe.encoders.slot_attention import SlotAttention
from ocpipe.encoders.vit import ImageNetPreprocess, ViT, grid_pool

TINY = dict(dim=64, depth=2, heads=4)
TINY_SLOTS = dict(input_dim=64, slot_dim=32, num_slots=7, iterations=3, mlp_hidden_dim=64)


def test_vit_b16_has_exactly_the_official_dino_keys_and_shapes():
    sd = ViT().state_dict()
    expected = {"cls_token": (1, 1, 768), "pos_embed": (1, 197, 768), "patch_embed.proj.weight": (768, 3, 16, 16),
                "patch_embed.proj.bias": (768,), "norm.weight": (768,), "norm.bias": (768,)}
    for i in range(12):
        b = f"blocks.{i}."
        expected.update({b + "norm1.weight": (768,), b + "norm1.bias": (768,), b + "attn.qkv.weight": (2304, 768),
                         b + "attn.qkv.bias": (2304,), b + "attn.proj.weight": (768, 768), b + "attn.proj.bias": (768,),
                         b + "norm2.weight": (768,), b + "norm2.bias": (768,), b + "mlp.fc1.weight": (3072, 768),
                         b + "mlp.fc1.bias": (3072,), b + "mlp.fc2.weight": (768, 3072), b + "mlp.fc2.bias": (768,)})
    assert {k: tuple(v.shape) for k, v in sd.items()} == expected


@pytest.mark.parametrize("size, patches", [(128, 64), (224, 196)])
def test_vit_shapes_with_position_embedding_interpolation(size, patches):
    vit = ViT(**TINY).eval()
    x = torch.randn(2, 3, size, size)
    tokens = vit.forward_features(x)
    assert tokens.shape == (2, 1 + patches, 64)
    assert vit.cls(x).shape == (2, 64) and vit.patch_tokens(x).shape == (2, patches, 64)
    assert grid_pool(vit.patch_tokens(x), 4).shape == (2, 16, 64)


def test_dino_layout_round_trip_and_wrapped_variants(tmp_path):
    vit = ViT(**TINY).eval()
    CK.write_dino_layout(vit, tmp_path / "dino.pth")
    loaded = CK.load_dino_vit(tmp_path / "dino.pth", **TINY)
    x = torch.randn(1, 3, 64, 64)
    torch.testing.assert_close(loaded.forward_features(x), vit.forward_features(x))
    # DINO's training checkpoints: teacher.backbone.* plus a projection head
    wrapped = {
        "teacher": {f"backbone.{k}": v for k, v in vit.state_dict().items()} | {"head.mlp.0.weight": torch.zeros(2)}
    }
    torch.save(wrapped, tmp_path / "full.pth")
    torch.testing.assert_close(
        CK.load_dino_vit(tmp_path / "full.pth", **TINY).forward_features(x), vit.forward_features(x)
    )


def test_wrong_layout_lists_the_keys(tmp_path):
    sd = ViT(**TINY).state_dict()
    sd["blocks.0.attn.in_proj.weight"] = sd.pop("blocks.0.attn.qkv.weight")
    torch.save(sd, tmp_path / "bad.pth")
    with pytest.raises(CK.CheckpointError, match=r"missing keys \['blocks.0.attn.qkv.weight'\].*in_proj"):
        CK.load_dino_vit(tmp_path / "bad.pth", **TINY)


def test_missing_file_names_the_config_key_and_source(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"encoders.dino.checkpoint.*dino_vitbase16_pretrain.pth"):
        CK.load_dino_vit(tmp_path / "nope.pth", config_key="encoders.dino.checkpoint")
    with pytest.raises(FileNotFoundError, match=r"encoders.spot.checkpoint.*spot"):
        CK.load_spot(None, config_key="encoders.spot.checkpoint")


def test_spot_layout_round_trip_ignores_decoder_and_second_encoder(tmp_path):
    vit, sa = ViT(**TINY).eval(), SlotAttention(**TINY_SLOTS).eval()
    CK.write_spot_layout(vit, sa, tmp_path / "checkpoint.pt.tar")
    raw = torch.load(tmp_path / "checkpoint.pt.tar", weights_only=False)
    assert {"epoch", "model", "optimizer"} <= set(raw) and "slot_attn.slots_init.weight" in raw["model"]
    assert any(k.startswith("second_encoder.") for k in raw["model"]) and "bos_tokens" in raw["model"]
    vit2, sa2 = CK.load_spot(tmp_path / "checkpoint.pt.tar", vit_kwargs=TINY, slot_kwargs=TINY_SLOTS)
    x = torch.randn(2, 3, 64, 64)
    feats = vit.forward_features(x, final_norm=False)[:, 1:]
    torch.testing.assert_close(sa2(vit2.forward_features(x, final_norm=False)[:, 1:]), sa(feats))


def test_slot_attention_is_permutation_equivariant_and_masks_partition_inputs():
    torch.manual_seed(0)
    sa = SlotAttention(**TINY_SLOTS).eval()
    x = torch.randn(3, 20, 64)
    slots, masks = sa(x)
    assert slots.shape == (3, 7, 32) and masks.shape == (3, 7, 20)
    torch.testing.assert_close(masks.sum(1), torch.ones(3, 20))
    perm = torch.randperm(7)
    slots_p, masks_p = sa(x, init_slots=sa.slots_init.weight[perm])
    torch.testing.assert_close(slots_p, slots[:, perm], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(masks_p, masks[:, perm], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(sa(x)[0], slots)  # learned init: deterministic


def test_preprocess_normalizes_once_and_refuses_normalized_input():
    prep = ImageNetPreprocess(32)
    img = torch.full((1, 3, 64, 64), 255, dtype=torch.uint8)
    out = prep(img)
    assert out.shape == (1, 3, 32, 32)
    torch.testing.assert_close(
        out[0, :, 0, 0], (1 - torch.tensor([0.485, 0.456, 0.406])) / torch.tensor([0.229, 0.224, 0.225])
    )
    torch.testing.assert_close(prep(img.float() / 255), out)  # [0, 1] floats are the same images
    with pytest.raises(ValueError, match="normalized"):
        prep(out)
