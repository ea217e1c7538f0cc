import numpy as np
import torch
from tolerances import EPS32, mean_atol, reduction_atol

from ocpipe.encoders import crop, ssl_slots
from ocpipe.sim import projection as P


def _scene_images(n=24, g=16, seed=0):
    """Blocks of flat colour on a textured background: a stand-in for cube / marker / table."""
    rng = np.random.default_rng(seed)
    imgs = np.zeros((n, 3, g, g), np.uint8)
    imgs[:, 0], imgs[:, 1], imgs[:, 2] = 180, 110, 60
    imgs += rng.integers(0, 20, imgs.shape, dtype=np.uint8)
    for i in range(n):
        y, x = rng.integers(0, g - 3, 2)
        imgs[i, :, y : y + 3, x : x + 3] = np.array([200, 20, 20])[:, None, None]
    return torch.from_numpy(imgs)


def test_training_is_deterministic_for_a_seed():
    cfg = ssl_slots.SSLSlotsConfig(grid=16, steps=6, batch_size=4, num_slots=4, slot_dim=16, feature_dim=16,
                                   warmup_steps=2, seed=3)
    imgs = _scene_images()
    a, curve_a, _ = ssl_slots.train(imgs, cfg, progress=False)
    b, curve_b, _ = ssl_slots.train(imgs, cfg, progress=False)
    for (k, va), vb in zip(a.state_dict().items(), b.state_dict().values()):
        # one-cpu: both trainings ran here, so the same kernels; another CPU kind would give other bits to both
        assert torch.equal(va, vb), k
    assert [c["loss"] for c in curve_a] == [c["loss"] for c in curve_b]


def test_masks_are_a_partition_of_unity_and_checkpoints_round_trip(tmp_path):
    cfg = ssl_slots.SSLSlotsConfig(grid=16, steps=2, batch_size=4, num_slots=5, slot_dim=16, feature_dim=16,
                                   warmup_steps=1)
    model, _, _ = ssl_slots.train(_scene_images(), cfg, progress=False)
    ssl_slots.save(model, tmp_path / "m.pt", {"workspace_min": [0, 0, 0], "workspace_max": [1, 1, 1]})
    model.double()  # the trained float32 weights, widened exactly: float32 round-off is no part of the checks
    x = _scene_images(4).double() / 255
    slots, masks = model.encode(x)
    assert slots.shape == (4, 5, 16) and masks.shape == (4, 5, 16, 16)
    # derived: float64, the softmax's sum over 5 slots, then the test's, of terms <= 1
    torch.testing.assert_close(masks.sum(1), torch.ones(4, 16, 16, dtype=torch.float64), rtol=0,
                               atol=reduction_atol(5, 1.0, depth=2))
    loaded, ckpt = ssl_slots.load(tmp_path / "m.pt")
    # the chained sums: 3 convolutions (<= 9 x 16 terms), colour and position (1), Slot Attention's LayerNorm (2),
    # MLP (2), k/v (1), then per iteration 12 (LayerNorm 2, q, scores, softmax, weights' sum, updates over the 256
    # cells, GRU, LayerNorm 2, MLP 2); the magnitude is the largest input or slot value
    atol = reduction_atol(16 * 16, max(1.0, float(slots.detach().abs().max())), depth=3 + 1 + 5 + 12 * cfg.iterations)
    # derived: float64; the loaded copy runs the same sums, at most in another order; a wrong weight is off by O(0.1)
    torch.testing.assert_close(loaded.double().encode(x)[1], masks, rtol=0, atol=atol)
    assert ckpt["workspace_max"] == [1, 1, 1]


def test_rarity_weights_favour_rare_colours_and_average_to_one():
    imgs = _scene_images()
    w = ssl_slots.rarity_weights(imgs, clip=1000.0)
    bins = ssl_slots.colour_bins(imgs)
    # derived: float64 weights averaging 1, each cast to float32 (<= eps32 / 2 of itself), averaged here in float64
    assert abs(w[bins].double().mean().item() - 1) < EPS32 / 2 + mean_atol(bins.numel(), float(w.max()))
    red = ssl_slots.colour_bins(torch.tensor([200, 20, 20], dtype=torch.uint8).view(1, 3, 1, 1)).item()
    counts = torch.bincount(bins.flatten(), minlength=len(w)).double()
    common = int(counts.argmax())
    # weights follow frequency^-power exactly below the clip
    expected = (counts[common] / counts[red]) ** 0.5
    # derived: two float32 casts and a float32 division, each <= eps32 / 2 relative
    assert abs(w[red] / w[common] - expected) < 2 * EPS32 * expected and expected > 2
    assert ssl_slots.rarity_weights(imgs, clip=2.0).max() <= 2.0


def test_crop_windows_cover_the_projected_workspace():
    R = 128
    K = P.intrinsic_from_fov(R, 90.0)[None]
    E = P.extrinsic_look_at([0.3, 0.0, 0.6], [-0.1, 0.0, 0.1])[None]
    lo, hi = [-0.1, -0.1, 0.0], [0.1, 0.1, 0.3]
    (x0, y0, size), = crop.crop_windows(K, E, R, lo, hi)
    uv = P.project_points(crop.workspace_corners(lo, hi), K[0], E[0])
    assert (uv[:, 0] >= x0).all() and (uv[:, 0] <= x0 + size).all()
    assert (uv[:, 1] >= y0).all() and (uv[:, 1] <= y0 + size).all()
    assert 0 <= x0 and x0 + size <= R and size < R
    # a moving camera (NaN matrices) gets the whole image
    assert crop.crop_windows(np.full((1, 3, 3), np.nan), np.full((1, 3, 4), np.nan), R, lo, hi).tolist() == [[0, 0, R]]


def test_crop_and_labels_select_the_same_cells():
    R, g = 32, 8
    rgb = torch.zeros(1, 1, R, R, 3, dtype=torch.uint8)
    seg = np.zeros((1, 1, R, R), np.uint16)
    rgb[0, 0, 8:12, 16:20] = 255
    seg[0, 0, 8:12, 16:20] = 7
    windows = np.array([[8, 4, 16]])  # x0=8, y0=4, 16 px -> 2 px per cell
    img = crop.crop_and_resize(rgb, windows, g)[0, 0, 0]
    lab = crop.crop_labels(seg, windows, g)[0, 0]
    assert ((img > 0.99) == (lab == 7)).all() and (lab == 7).sum() == 4
