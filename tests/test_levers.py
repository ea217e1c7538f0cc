"""The recipe levers: slot geometry, the privileged-state tokens, residual joint targets, the auxiliary object
loss, token normalization and the open-loop check on held-out demos."""

import numpy as np
import pytest
import torch
from policy_stores import policy_settings, write_stores

from ocpipe.encoders.state import state_tokens, yaw
from ocpipe.features.slot_geometry import full_image_windows, slot_geometry
from ocpipe.policy import normalization
from ocpipe.policy.training import load_data, load_policy, split_episodes, train
from ocpipe.policy.windows import Labels, action_frames, make_batch


def _quat_z(angle):
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def test_slot_geometry_of_a_box_mask_in_a_crop_window():
    masks = torch.zeros(1, 2, 3, 8, 8)
    masks[0, 0, 0, 2:4, 4:8] = 1.0  # rows 2-3, cols 4-7 of an 8x8 grid
    masks[0, 1, 1] = 1.0  # the whole grid
    windows = np.array([[16, 32, 64], [0, 0, 128]])  # camera 0's masks cover pixels x 16..80, y 32..96 of 128
    g = slot_geometry(masks, windows, 128)
    assert g.shape == (1, 2, 3, 5)
    u, v, area, su, sv = g[0, 0, 0].tolist()
    assert u == pytest.approx((16 + 6 / 8 * 64) / 128) and v == pytest.approx((32 + 3 / 8 * 64) / 128)
    assert area == pytest.approx(8 / 64)
    assert su == pytest.approx(np.std((np.arange(4, 8) + 0.5) / 8 * 64 / 128))
    assert sv == pytest.approx(np.std((np.arange(2, 4) + 0.5) / 8 * 64 / 128))
    assert g[0, 1, 1, :3].tolist() == pytest.approx([0.5, 0.5, 1.0])
    assert torch.isfinite(g).all()  # empty masks give finite numbers, not NaN
    assert (full_image_windows(2, 64) == np.array([[0, 0, 64], [0, 0, 64]])).all()


def test_state_tokens_encode_yaw_with_the_cubes_quarter_turn_symmetry():
    assert yaw(_quat_z(0.3)) == pytest.approx(0.3)
    a, b = state_tokens(np.zeros(3), _quat_z(0.3)), state_tokens(np.zeros(3), _quat_z(0.3 + np.pi / 2))
    assert a.shape == (1, 1, 5)
    np.testing.assert_allclose(a, b, atol=1e-6)
    c = state_tokens(np.array([0.1, -0.2, 0.02]), _quat_z(np.pi / 8))  # 4 * 22.5 deg = 90 deg
    np.testing.assert_allclose(c[0, 0], [0.1, -0.2, 0.02, 1.0, 0.0], atol=1e-6)
    d = state_tokens(np.array([0.1, -0.2, 0.02]), _quat_z(np.pi / 8), tcp_pos=np.array([0.0, 0.1, 0.2]))
    np.testing.assert_allclose(d[0, 0], [0.1, -0.2, 0.02, 1.0, 0.0, 0.1, -0.3, -0.18], atol=1e-6)


def test_residual_targets_round_trip_to_the_expert_actions():
    rng = np.random.default_rng(0)
    qpos = rng.normal(size=(20, 9)).astype(np.float32)
    action = rng.normal(size=(20, 8)).astype(np.float32)
    action[:, 7] = np.sign(action[:, 7])
    offsets = [0, 12, 20]
    labels = Labels.from_offsets(offsets, qpos, qpos, action)
    frames = np.arange(20)
    act = action_frames(frames, labels, 3)
    stats = normalization.residual_stats(action, qpos, frames, act)
    assert stats["action_mean"].shape == (3, 8)
    labels = Labels.from_offsets(
        offsets,
        qpos[:, :7],
        np.zeros((20, 0), np.float32),
        action,
        residual=(normalization.residual_base(qpos), stats["action_mean"], stats["action_std"]),
    )
    model_space = labels.targets(frames, act)
    np.testing.assert_allclose(model_space[..., :7].reshape(-1, 7).std(0), 1.0, rtol=1e-4)
    back = normalization.action_from_model(model_space, stats, qpos=qpos[:, :7])
    np.testing.assert_allclose(back, action[act], atol=1e-5)


def test_split_holds_out_the_last_episodes():
    train_frames, val = split_episodes([0, 30, 55, 95], 1)
    assert train_frames.tolist() == list(range(55)) and val.tolist() == list(range(55, 95))
    with pytest.raises(ValueError, match="val_episodes"):
        split_episodes([0, 30], 1, "store.zarr")


def test_aux_targets_geometry_and_token_norm_reach_the_model(tmp_path):
    features, frames = write_stores(tmp_path)
    policy = policy_settings(slot_geometry=True, token_norm="zscore", aux_object_weight=1.0, val_episodes=1)
    tokens, labels, stats, meta, (tr, val) = load_data(policy, features, frames)
    assert meta["D"] == 16 + 5 and tokens[0:3].shape == (3, 2, 7, 21)
    assert len(val) == 40 and tr.max() < val.min()
    assert stats["token_mean"].shape == (21,) and stats["aux_mean"].shape == (3,)
    batch = make_batch(tokens[0:10], 0, np.arange(3, 8), labels, 3, 4, [0, 1])
    assert batch["aux"].shape == (5, 3)
    table = train(policy, 0, features, frames, tmp_path / "run", progress=False)
    assert table["loss_aux"][-1] > 0 and {"val_joint_err_rad", "val_gripper_agree"} <= set(table.columns)
    model, loaded_stats, _, _ = load_policy(tmp_path / "run" / "checkpoints" / "epoch_0004.pt")
    np.testing.assert_allclose(model.token_mean.numpy(), stats["token_mean"])
    pred, aux = model(batch["tokens"], batch["proprio"], batch["goal"], aux=True)
    assert pred.shape == (5, 4, 8) and aux["object_pos"].shape == (5, 3) and aux["readout"] is None


def test_geometry_needs_a_store_with_masks(tmp_path):
    import zarr

    features, frames = write_stores(tmp_path)
    del zarr.open_group(str(features), mode="a")["geometry"]
    with pytest.raises(ValueError, match="slot_geometry"):
        load_data(policy_settings(slot_geometry=True), features, frames)


def test_openloop_error_is_zero_for_a_policy_that_returns_the_expert_chunk(tmp_path):
    """The metric itself: feed it a 'model' that outputs the exact normalized targets."""
    from ocpipe.policy.training import openloop_error
    from ocpipe.policy.windows import ChunkWindowLoader

    features, frames = write_stores(tmp_path)
    for targets in ("absolute", "residual"):
        policy = policy_settings(joint_targets=targets, val_episodes=1)
        tokens, labels, stats, _, (_, val) = load_data(policy, features, frames)
        loader = ChunkWindowLoader(tokens, labels, 3, 4, 16, [0, 1], 0, frames=val)
        truth = {}
        for b in loader.epoch(0):
            for f, a in zip(b["frame"].tolist(), b["action"]):
                truth[f] = a

        class Oracle(torch.nn.Module):
            current = None

            def forward(self, tokens, proprio, goal, first=None, tcp=None, truth=truth):
                return torch.stack([truth[f] for f in Oracle.current])

        def patched_epoch(epoch, _orig=loader.epoch):
            for b in _orig(epoch):
                Oracle.current = b["frame"].tolist()
                yield b

        loader.epoch = patched_epoch
        err = openloop_error(Oracle(), loader, labels, stats, policy, "cpu")
        assert err["val_joint_err_rad"] == pytest.approx(0.0, abs=1e-5) and err["val_gripper_agree"] == 1.0


def test_proprio_noise_changes_training_and_stays_seeded(tmp_path):
    features, frames = write_stores(tmp_path)
    losses = {}
    for name, noise in (("a", 0.0), ("b", 0.5), ("c", 0.5)):
        table = train(
            policy_settings(proprio_noise=noise, epochs=1, save_every=1),
            0,
            features,
            frames,
            tmp_path / name,
            progress=False,
        )
        losses[name] = table["loss"].to_list()
    assert losses["b"] == losses["c"] and losses["a"] != losses["b"]
