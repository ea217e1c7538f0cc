"""ViT, Slot Attention and the official DINO / SPOT checkpoint layouts, on checkpoints written here."""

import pytest
import torch
from tolerances import EPS32, reduction_atol

from ocpipe.encoders import checkpoints as CK
from ocpipe.encoders.slot_attention import SlotAttention
from ocpipe.encoders.vit import IMAGENET_STD, ImageNetPreprocess, ViT, grid_pool

TINY = dict(dim=64, depth=2, heads=4)
TINY_SLOTS = dict(input_dim=64, slot_dim=32, num_slots=7, iterations=3, mlp_hidden_dim=64)


def largest(*tensors) -> float:
    return max(float(t.detach().abs().max()) for t in tensors)


def vit_atol(vit: ViT, magnitude: float, final_norm: bool = True) -> float:
    """Two float64 evaluations of one ViT in other summation orders: the patch projection (3 p^2 terms), per block
    10 chained sums (two LayerNorms of 2, qkv, scores, softmax, attention-weighted mean, proj, fc1, fc2 over the
    hidden width), then the final LayerNorm (2)."""
    n = max(3 * vit.patch**2, vit.blocks[0].mlp.fc1.out_features)
    return reduction_atol(n, magnitude, depth=1 + 10 * len(vit.blocks) + 2 * final_norm)


def slots_atol(sa: SlotAttention, inputs: int, magnitude: float) -> float:
    """The same for Slot Attention: LayerNorm (2), MLP (2), input LayerNorm (2), k/v (1), then per iteration 12
    (LayerNorm 2, q, scores, softmax over slots, weights' sum, updates, GRU, LayerNorm 2, MLP 2) over at most
    max(input width, inputs, MLP hidden width) terms."""
    it = sa.slot_attention
    n = max(sa.layer_norm.normalized_shape[0], inputs, it.mlp[0].out_features)
    return reduction_atol(n, magnitude, depth=7 + 12 * it.iterations)


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
    # DINO's training checkpoints: teacher.backbone.* plus a projection head
    wrapped = {
        "teacher": {f"backbone.{k}": v for k, v in vit.state_dict().items()} | {"head.mlp.0.weight": torch.zeros(2)}
    }
    torch.save(wrapped, tmp_path / "full.pth")
    vit.double()  # the float32 weights, widened exactly: float32 round-off is no part of the check
    x = torch.randn(1, 3, 64, 64, dtype=torch.float64)
    want = vit.forward_features(x)
    atol = vit_atol(vit, largest(x, want))
    # derived: float64, the same weights through the same sums (vit_atol); a misplaced weight is off by O(0.1)
    torch.testing.assert_close(CK.load_dino_vit(tmp_path / "dino.pth", **TINY).double().forward_features(x), want,
                               rtol=0, atol=atol)
    # derived: as above
    torch.testing.assert_close(CK.load_dino_vit(tmp_path / "full.pth", **TINY).double().forward_features(x), want,
                               rtol=0, atol=atol)


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
    vit2, sa2 = (m.double() for m in CK.load_spot(tmp_path / "checkpoint.pt.tar", vit_kwargs=TINY,
                                                   slot_kwargs=TINY_SLOTS))
    vit.double()
    sa.double()
    x = torch.randn(2, 3, 64, 64, dtype=torch.float64)
    feats = vit.forward_features(x, final_norm=False)[:, 1:]
    want = sa(feats)
    magnitude = largest(x, feats, *want)
    atol = vit_atol(vit, magnitude, final_norm=False) + slots_atol(sa, feats.shape[1], magnitude)
    # derived: float64, the ViT's then Slot Attention's sums (vit_atol + slots_atol); a wrong weight is off by O(0.1)
    torch.testing.assert_close(sa2(vit2.forward_features(x, final_norm=False)[:, 1:]), want, rtol=0, atol=atol)


def test_slot_attention_is_permutation_equivariant_and_masks_partition_inputs():
    torch.manual_seed(0)
    sa = SlotAttention(**TINY_SLOTS).eval().double()
    x = torch.randn(3, 20, 64, dtype=torch.float64)
    slots, masks = sa(x)
    assert slots.shape == (3, 7, 32) and masks.shape == (3, 7, 20)
    # derived: float64, the softmax's sum over 7 slots, then the test's, of terms <= 1
    torch.testing.assert_close(masks.sum(1), torch.ones(3, 20, dtype=torch.float64), rtol=0,
                               atol=reduction_atol(7, 1.0, depth=2))
    perm = torch.randperm(7)
    slots_p, masks_p = sa(x, init_slots=sa.slots_init.weight[perm])
    atol = slots_atol(sa, x.shape[1], largest(x, slots))
    # derived: float64; permuted slots change only the order of the sums over slots (slots_atol); a slot that broke
    # equivariance would be off by O(0.1)
    torch.testing.assert_close(slots_p, slots[:, perm], rtol=0, atol=atol)
    torch.testing.assert_close(masks_p, masks[:, perm], rtol=0, atol=atol)  # derived: as above
    # exact: learned init, no sampling: the same module on the same tensor runs the same operations in the same order
    torch.testing.assert_close(sa(x)[0], slots, rtol=0, atol=0)


def test_preprocess_normalizes_once_and_refuses_normalized_input():
    prep = ImageNetPreprocess(32)
    img = torch.full((1, 3, 64, 64), 255, dtype=torch.uint8)
    out = prep(img)
    assert out.shape == (1, 3, 32, 32)
    # derived: float32 (a uint8 image is widened to float32): the antialiased resize of the constant image sums <= 5
    # weights per pass in two passes; both sides then subtract (at <= 0.6) and divide (to <= 2.64) with one rounding
    # each (<= 2 eps32 in all before the division by std >= 0.224)
    torch.testing.assert_close(
        out[0, :, 0, 0], (1 - torch.tensor([0.485, 0.456, 0.406])) / torch.tensor([0.229, 0.224, 0.225]),
        rtol=0, atol=(reduction_atol(5, 1.0, depth=2, eps=EPS32) + 2 * EPS32) / min(IMAGENET_STD),
    )
    # exact: [0, 1] floats made with the product's own float() / 255 are the same numbers, through the same operations
    torch.testing.assert_close(prep(img.float() / 255), out, rtol=0, atol=0)
    with pytest.raises(ValueError, match="normalized"):
        prep(out)
