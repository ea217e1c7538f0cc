"""The recipe's departures from the study: the privileged-state tokens, residual joint targets, the auxiliary
object loss, token normalization and the open-loop check on held-out demos."""

import numpy as np
import pytest
import torch
from policy_stores import policy_settings, write_stores
from tolerances import EPS32, gamma, mean_atol

from ocpipe.encoders.state import state_tokens, yaw
from ocpipe.policy import data
from ocpipe.policy.checkpoint import load_policy
from ocpipe.policy.data import split_episodes
from ocpipe.policy.training import openloop_error, train
from ocpipe.policy.windows import action_frames, make_batch


def _quat_z(angle):
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def test_state_tokens_encode_yaw_with_the_cubes_quarter_turn_symmetry():
    # derived: cos, sin, 4 products and an arctan2 in float64 (<= ~1e-15); approx's 1e-6 default covers it and is
    # far below a wrong yaw (the symmetry under test shifts it by pi/2)
    assert yaw(_quat_z(0.3)) == pytest.approx(0.3)
    a, b = state_tokens(np.zeros(3), _quat_z(0.3)), state_tokens(np.zeros(3), _quat_z(0.3 + np.pi / 2))
    assert a.shape == (1, 1, 5)
    # derived: float32 tokens of size <= 1, computed in float64 (~1e-15 apart): the cast may round the two one
    # float32 ulp apart, <= EPS32
    np.testing.assert_allclose(a, b, rtol=0, atol=EPS32)
    c = state_tokens(np.array([0.1, -0.2, 0.02]), _quat_z(np.pi / 8))  # 4 * 22.5 deg = 90 deg
    # derived: float32 tokens of size <= 1 against decimal literals: half a float32 ulp plus float64 round-off
    np.testing.assert_allclose(c[0, 0], [0.1, -0.2, 0.02, 1.0, 0.0], rtol=0, atol=EPS32)
    d = state_tokens(np.array([0.1, -0.2, 0.02]), _quat_z(np.pi / 8), tcp_pos=np.array([0.0, 0.1, 0.2]))
    # derived: as above, the offsets one float64 subtraction more
    np.testing.assert_allclose(d[0, 0], [0.1, -0.2, 0.02, 1.0, 0.0, 0.1, -0.3, -0.18], rtol=0, atol=EPS32)


def test_split_holds_out_the_last_episodes():
    train_frames, val = split_episodes([0, 30, 55, 95], 1)
    assert train_frames.tolist() == list(range(55)) and val.tolist() == list(range(55, 95))
    with pytest.raises(ValueError, match="val_episodes"):
        split_episodes([0, 30], 1, "store.zarr")


def test_aux_targets_and_token_norm_reach_the_model(tmp_path):
    features, frames = write_stores(tmp_path)
    policy = policy_settings(token_norm="zscore", aux_object_weight=1.0, val_episodes=1)
    d = data.load(policy, features, frames)
    assert d.meta["D"] == 16 and len(d.val_frames) == 40 and d.train_frames.max() < d.val_frames.min()
    batch = make_batch(d.tokens[0:10], 0, np.arange(3, 8), d.labels, 3, 4, [0, 1])
    assert batch["aux"].shape == (5, 3)
    table = train(policy, 0, features, frames, tmp_path / "run", progress=False)
    assert table["loss_aux"][-1] > 0 and {"val_joint_err_rad", "val_gripper_agree"} <= set(table.columns)
    model, _, _ = load_policy(tmp_path / "run" / "checkpoints" / "epoch_0004.pt")
    # the token statistics are the training frames' (pooled over cameras and slots), kept in the checkpoint
    x = np.asarray(d.tokens[: d.train_frames[-1] + 1], np.float64).reshape(-1, 16)
    # derived: the product too takes the float64 mean of these len(x) float16 tokens (two summation orders differ by
    # at most mean_atol) and keeps it in a float32 buffer (half a float32 ulp, within rtol EPS32)
    np.testing.assert_allclose(model.normalizer.tokens.mean.numpy(), x.mean(0), rtol=EPS32,
                               atol=mean_atol(len(x), np.abs(x).max()))
    aux = d.labels.aux[d.train_frames]
    # derived: the product averages the float32 labels in float32: a float32 sum of len(aux) terms of size <= max|aux|
    # (mean_atol at EPS32), against their float64 mean here
    np.testing.assert_allclose(model.normalizer.aux.mean.numpy(), aux.astype(np.float64).mean(0), rtol=0,
                               atol=mean_atol(len(aux), np.abs(aux).max(), eps=EPS32))
    out = model(batch["tokens"], batch["proprio"], batch["goal"])
    assert out.actions.shape == (5, 4, 8) and out.object_pos.shape == (5, 3) and out.readout is None


@pytest.mark.parametrize("targets", ["absolute", "residual"])
def test_openloop_error_is_zero_for_a_policy_that_returns_the_expert_chunk(tmp_path, targets):
    """The metric itself: feed it a 'model' whose output de-normalizes to the expert's own chunk."""
    features, frames = write_stores(tmp_path)
    policy = policy_settings(joint_targets=targets, val_episodes=1)
    train({**policy, "epochs": 1, "save_every": 1}, 0, features, frames, tmp_path / "run", progress=False)
    model, settings, _ = load_policy(tmp_path / "run" / "checkpoints" / "epoch_0001.pt")
    d = data.load(policy, features, frames)

    class Oracle(torch.nn.Module):
        normalizer = model.normalizer

        def forward(self, tokens, proprio, goal):  # the batch's own targets, found by its proprio (joints)
            qpos = torch.from_numpy(d.labels.qpos)
            frames_ = [int(torch.nonzero((torch.from_numpy(d.labels.proprio) == p[-1]).all(1))[0]) for p in proprio]
            chunk = action_frames(np.array(frames_), d.labels, settings.network.horizon)
            want = torch.from_numpy(d.labels.action[chunk])
            return type("Out", (), {"actions": model.normalizer.actions_to_model(want, qpos[frames_])})

    err = openloop_error(Oracle(), d, settings, "cpu")
    M = float(np.abs(d.labels.action[:, :7]).max() + np.abs(d.labels.qpos[:, :7]).max())  # largest target + joint
    # derived: the float32 round trip (a - q - m) / s * s + m + q: 6 float32 ops on values <= 2M, so each joint is
    # off by at most gamma_6 * 2M, and so is their mean
    assert err["val_joint_err_rad"] == pytest.approx(0.0, abs=gamma(6, EPS32) * 2 * M)
    assert err["val_gripper_agree"] == 1.0
