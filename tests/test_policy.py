import itertools

import numpy as np
import polars as pl
import pytest
import torch
from policy_stores import policy_settings, write_stores
from tolerances import EPS32, EPS64, decoder_atols, gamma, mean_atol, reduction_atol

from ocpipe.policy import data, observation
from ocpipe.policy.checkpoint import load_policy
from ocpipe.policy.model import PROPRIO_DIMS, SequencePolicy, loss_terms
from ocpipe.policy.normalization import Normalizer
from ocpipe.policy.settings import PolicySettings
from ocpipe.policy.training import train
from ocpipe.policy.weighting import loss_weights
from ocpipe.policy.windows import ChunkWindowLoader, Labels, action_frames, progress, window_frames


def inputs(policy, B=3, K=7, D=16, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    T, C = policy["window"], len(policy["cameras"])
    P = PROPRIO_DIMS[policy["proprio"]]
    G = {"none": 0, "2d": 4, "3d": 3}[policy["goal"]]
    return (torch.randn(B, T, C, K, D, generator=g, dtype=dtype), torch.randn(B, T, P, generator=g, dtype=dtype),
            torch.randn(B, T, G, generator=g, dtype=dtype))


@pytest.mark.parametrize("visual_head,fusion", [("tokens", "concat"), ("tokens", "cross_attention"),
                                                ("flatten", "concat"), ("deepsets", "concat"),
                                                ("weighted_pool", "concat"), ("slot_transformer", "concat")])
def test_changing_a_future_timestep_leaves_earlier_outputs_unchanged(visual_head, fusion):
    policy = policy_settings(window=5, visual_head=visual_head, fusion=fusion)
    torch.manual_seed(0)
    model = SequencePolicy(policy, 7, 16).eval().double()
    tokens, proprio, goal = inputs(policy, dtype=torch.float64)
    seq = model.tokens(tokens, proprio, goal)[0]
    before = model.action_states(seq)  # (B, T, W): every step's action token
    tokens[:, 3] += 1.0
    proprio[:, 3] += 1.0
    goal[:, 3] += 1.0
    after = model.action_states(model.tokens(tokens, proprio, goal)[0])
    atol, _ = decoder_atols(len(model.decoder.layers), seq.shape, float(seq.detach().abs().max()), 0.0)
    # derived: float64; the masked later tokens add exact zeros, so at most the sums' reordering differs
    torch.testing.assert_close(after[:, :3], before[:, :3], rtol=0, atol=atol)
    assert not torch.allclose(after[:, 3], before[:, 3], rtol=0, atol=atol)  # derived: the change is O(1)


@pytest.mark.parametrize("layers,window", [(1, 1), (2, 5), (3, 4)])
def test_the_current_action_state_is_the_full_decoders_last_action_token(layers, window):
    """forward reads only the last token, so the last layer computes only that row; it must be the row the whole
    decoder gives, and its gradients the same."""
    policy = policy_settings(window=window, layers=layers, goal="2d", cameras=[0, 1])
    torch.manual_seed(0)
    model = SequencePolicy(policy, 7, 16).eval().double()
    seq = model.tokens(*inputs(policy, dtype=torch.float64))[0]
    full = model.action_states(seq)[:, -1]
    fast = model.current_action_state(seq)
    atol, grad_atol = decoder_atols(layers, seq.shape, float(seq.detach().abs().max()),
                                    float(full.detach().abs().max()))
    # derived: float64, the two paths sum in another order (decoder_atols); a wrong row would be off by O(1)
    torch.testing.assert_close(fast, full, rtol=0, atol=atol)
    grads = [torch.autograd.grad(out.square().sum(), list(model.decoder.parameters())) for out in (full, fast)]
    for a, b in zip(*grads):
        torch.testing.assert_close(b, a, rtol=0, atol=grad_atol)  # derived: decoder_atols, the backward pass


VARIANTS = [dict(zip(("goal", "proprio", "visual_head", "gripper", "action_head", "cameras"), v)) for v in
            itertools.product(["none", "2d", "3d"], ["joints7", "qpos9_global"], ["tokens", "deepsets"],
                              ["regression", "bce"], ["linear", "tanh"], [[0], [0, 1]])]


@pytest.mark.parametrize("variant", VARIANTS, ids=lambda v: "-".join(str(x) for x in v.values()))
def test_every_variant_predicts_h_by_8_actions(variant):
    policy = policy_settings(**variant)
    model = SequencePolicy(policy, 7, 16)
    out = model(*inputs(policy)).actions
    assert out.shape == (3, policy["horizon"], 8)
    if variant["action_head"] == "tanh":
        assert out[..., :7].abs().max() <= 1.0  # exact: tanh's range, which float32 keeps
    terms = loss_terms(out, torch.zeros_like(out), torch.ones_like(out), variant["gripper"] == "bce")
    terms["loss"].backward()


@pytest.mark.parametrize("K,D", [(1, 768), (16, 768), (196, 32)])
def test_dino_readouts_of_any_token_count(K, D):
    policy = policy_settings(window=1, horizon=1)
    model = SequencePolicy(policy, K, D)
    assert model.per_step == 2 * K + 3
    assert model(*inputs(policy, K=K, D=D)).actions.shape == (3, 1, 8)


def zscore_atol(x, standardize, z, stats_eps=EPS64) -> float:
    """How far z-scores' float64 mean and population std may sit from 0 and 1, per column d, the worst column's:
    the statistics are summed over n rows in their own dtype (``stats_eps``: Normalizer.fit takes proprio's in
    float64, the goal's in its float32) and kept as float32 (eps32 / 2 of the mean, shifting z by |m_d| / s_d of
    that, and of the std); z = (x - m) / s rounds twice in float32, each relative to |z|."""
    x = np.asarray(x, np.float64)
    n, m, s = len(x), standardize.mean.double().numpy(), standardize.std.double().numpy()
    z_max = z.abs().amax(0).double().numpy()
    summed = np.array([mean_atol(n, a, eps=stats_eps) for a in np.abs(x).max(0)]) / s + gamma(n, stats_eps) * z_max
    return float((EPS32 * (np.abs(m) / s + z_max + 1) + summed).max())


def normalizer(**overrides) -> Normalizer:
    policy = PolicySettings.of(policy_settings(**overrides))
    return Normalizer(policy, 7, 16, len(policy.stores.cameras), PROPRIO_DIMS[policy.network.proprio], 4)


def fit(norm: Normalizer, x=None, action=None, **overrides):
    """Fit on proprio inputs ``x`` and absolute actions, the other inputs zero."""
    policy = PolicySettings.of(policy_settings(**overrides))
    n = len(x if x is not None else action)
    norm.fit(policy, proprio=np.zeros((n, PROPRIO_DIMS[policy.network.proprio])) if x is None else x,
             goal=np.zeros((n, 4), np.float32), action=np.zeros((n, 8), np.float32) if action is None else action,
             qpos_at=np.zeros((n, 9), np.float32), pose=None, aux=None)


def test_gripper_is_a_hard_step_and_joints_are_denormalized():
    norm = normalizer()
    mean, std = np.arange(8, dtype=np.float32) * 0.1, np.full(8, 2.0, np.float32)
    mean[7], std[7] = 0, 1
    norm.action.set(mean, std)
    pred = torch.zeros(1, 3, 8)
    pred[..., 0] = 1.0
    pred[0, :, 7] = torch.tensor([0.3, -0.2, 0.0])
    out = norm.actions_from_model(pred, None)[0].numpy()
    assert out[:, 7].tolist() == [1.0, -1.0, -1.0]
    np.testing.assert_array_equal(out[:, 0], 2.0)  # exact: 1 x 2 + 0 in float32
    # derived: 0 x 2 + the float32 mean, which holds 0.1 k rounded once (<= eps32 / 2 relative)
    np.testing.assert_allclose(out[:, 1:7], np.tile(np.arange(1, 7) * 0.1, (3, 1)), rtol=EPS32)
    raw = np.array([[0.1] * 7 + [1.0], [0.3] * 7 + [-1.0]], np.float32)
    fit(norm, action=raw)
    assert norm.action.mean[7] == 0 and norm.action.std[7] == 1  # gripper untouched
    # exact: the gripper passes through untouched
    np.testing.assert_array_equal(norm.actions_to_model(torch.from_numpy(raw)[:, None], None)[:, 0, 7], [1.0, -1.0])


def test_residual_targets_are_relative_to_the_current_joints_and_come_back_exactly():
    norm = normalizer(joint_targets="residual")
    rng = np.random.default_rng(0)
    qpos, action = rng.normal(0, 1, (50, 9)).astype(np.float32), rng.normal(0, 1, (50, 4, 8)).astype(np.float32)
    action[..., 7] = np.sign(action[..., 7])
    norm.fit(PolicySettings.of(policy_settings(joint_targets="residual")), proprio=qpos[:, :7], goal=np.zeros((50, 4)),
             action=action, qpos_at=qpos, pose=None, aux=None)
    assert norm.action.mean.shape == (4, 8)
    # float64 inputs: the float32 statistics promote exactly, so the round trip is float64 arithmetic
    action64, qpos64 = torch.from_numpy(action.astype(np.float64)), torch.from_numpy(qpos.astype(np.float64))
    z = norm.actions_to_model(action64, qpos64)
    residual = action[..., :7] - qpos[:, None, :7]
    std = norm.action.std[..., :7].numpy()
    atol = (mean_atol(50, np.abs(residual).max(), eps=EPS32) / std.min() + mean_atol(50, float(z.abs().max())))
    # derived: the statistics were taken in float32 over 50 rows, and the mean of z over 50 rows in float64
    np.testing.assert_allclose(z[..., :7].mean((0,)).numpy(), 0.0, atol=atol)  # per (horizon step, joint)
    back = norm.actions_from_model(z, qpos64).numpy()
    # every value on the way (a - q - m, and back) is at most |a| + |q| + |m|
    largest = float(np.abs(action).max() + np.abs(qpos).max() + norm.action.mean.abs().max())
    # derived: subtract, divide, multiply, add back: four float64 operations on values this large
    np.testing.assert_allclose(back, action, rtol=0, atol=reduction_atol(4, largest))


def test_loss_weights_follow_the_spec_numbers():
    p = torch.tensor([0.0, 0.35, 0.39, 0.4, 0.85, 1.0])
    u = loss_weights("u_shaped", p)[:, 0]
    # derived: float32 weights near 2 (round-off ~2.4e-7); 0.01 still tells the peak (2) from its tails
    assert u[1] == pytest.approx(2.0, abs=0.01) and u[4] == pytest.approx(2.0, abs=0.01)
    # derived: as above; 1e-4 tells a sigma of 0.15 (u = 1.0657) from 0.14 (1.0439) or 0.16 (1.0914)
    assert u[0] == pytest.approx(1 + np.exp(-0.5 * (0.35 / 0.15) ** 2), abs=1e-4)  # sigma 0.15
    d = loss_weights("dim_decoupled", p)
    assert d[2].tolist() == [1.0] * 7 + [3.0] and d[3].tolist() == [3.0] * 7 + [1.0]
    assert (loss_weights("time", p, epoch=99, warmup_epochs=100) == 1).all()
    # exact: 1 + p in float32 both sides
    np.testing.assert_array_equal(loss_weights("time", p, epoch=100, warmup_epochs=100)[:, 3], 1 + p.numpy())
    assert (loss_weights("uniform", p) == 1).all()
    with pytest.raises(ValueError, match="policy.loss_weighting"):
        loss_weights("cubic", p)


def test_global_9dof_normalization_squashes_the_fingers_and_grouped_restores_them():
    rng = np.random.default_rng(0)
    qpos = np.concatenate([rng.normal([0, 0.3, 0, -2.2, 0, 2.5, 0.8], 0.4, (5000, 7)),
                           rng.uniform(0.018, 0.040, (5000, 1)).repeat(2, 1)], 1).astype(np.float32)

    def spread(mode):
        norm = normalizer(proprio=mode)
        fit(norm, x=qpos, proprio=mode)
        z = norm.proprio(torch.from_numpy(qpos))
        return z[:, 7:].double().std(0, unbiased=False).numpy(), zscore_atol(qpos, norm.proprio, z)

    assert spread("qpos9_global")[0].max() < 0.01  # fingers nearly constant: the thesis' pathology
    std, atol = spread("qpos9_grouped")
    np.testing.assert_allclose(std, 1.0, rtol=0, atol=atol)  # derived: zscore_atol


def test_joints7_tcp_appends_the_tcp_and_zscores_every_dimension():
    rng = np.random.default_rng(0)
    labels = {"qpos": rng.normal(0, 0.5, (500, 9)), "tcp_pos": rng.normal([0, 0, 0.2], 0.05, (500, 3))}
    policy = PolicySettings.of(policy_settings(proprio="joints7_tcp"))
    x = observation.proprio(policy, labels)
    # derived: the float64 labels rounded once to float32 (<= eps32 / 2 relative)
    np.testing.assert_allclose(x, np.concatenate([labels["qpos"][:, :7], labels["tcp_pos"]], 1), rtol=EPS32)
    norm = normalizer(proprio="joints7_tcp")
    fit(norm, x=x, proprio="joints7_tcp")
    z = norm.proprio(torch.from_numpy(x))
    atol = zscore_atol(x, norm.proprio, z)
    np.testing.assert_allclose(z.double().mean(0), 0, rtol=0, atol=atol)  # derived: zscore_atol
    np.testing.assert_allclose(z.double().std(0, unbiased=False), 1, rtol=0, atol=atol)  # derived: zscore_atol
    assert observation.proprio(PolicySettings.of(policy_settings()), labels).shape == (500, 7)


def test_a_joints7_tcp_policy_trains_on_the_stores_tcp_and_keeps_its_stats(tmp_path):
    features, frames = write_stores(tmp_path)
    train(policy_settings(proprio="joints7_tcp", epochs=1, save_every=1), 0, features, frames, tmp_path / "run",
          progress=False)
    model, policy, _ = load_policy(tmp_path / "run" / "checkpoints" / "epoch_0001.pt")
    assert policy.network.proprio == "joints7_tcp" and model.normalizer.proprio.mean.shape == (10,)
    assert model.sources[1].net[0].in_features == 10  # the proprioception source


def batch_of(policy, features, frames, n=8):
    d = data.load(policy, features, frames)
    return d, next(ChunkWindowLoader(d.tokens, d.labels, policy["window"], policy["horizon"], n, policy["cameras"],
                                     0).epoch(0))


def test_object_readout_learns_the_pose_and_the_action_loss_cannot_reshape_it(tmp_path):
    features, frames = write_stores(tmp_path)
    policy = policy_settings(object_readout=True, epochs=4, save_every=4)
    _, batch = batch_of(policy, features, frames)
    assert batch["readout"].shape == (8, policy["window"], 5)
    torch.manual_seed(0)
    model = SequencePolicy(policy, 7, 16)
    out = model(batch["tokens"], batch["proprio"], batch["goal"])
    assert out.readout.shape == (8, policy["window"], 5)
    loss_terms(out.actions, batch["action"], torch.ones_like(out.actions), False)["loss"].backward()
    assert all(p.grad is None for p in model.object_readout.parameters())  # detached from the action loss
    log = train(policy, 0, features, frames, tmp_path / "run", progress=False)
    assert log["loss_readout"][-1] < log["loss_readout"][0]


def test_a_given_estimate_changes_only_what_the_policy_sees(tmp_path):
    features, frames = write_stores(tmp_path)
    policy = policy_settings(object_readout=True)
    _, batch = batch_of(policy, features, frames)
    model = SequencePolicy(policy, 7, 16).eval()
    args = (batch["tokens"], batch["proprio"], batch["goal"])
    clean = model(*args)
    # an estimate given from outside (the closed loop's per-step read-outs, or the true pose) is what the policy
    # sees; the read-out itself (and its loss) stays
    assert torch.equal(clean.actions, model(*args, readout_seen=clean.readout).actions)  # exact: the same numbers in
    shifted = model(*args, readout_seen=clean.readout + 0.5)
    # derived: a 0.5 shift moves the actions by O(0.1), far above allclose's 1e-5; exact: the read-out never sees it
    assert not torch.allclose(clean.actions, shifted.actions) and torch.equal(clean.readout, shifted.readout)


def test_without_visual_tokens_the_policy_sees_the_slots_only_through_its_read_out(tmp_path):
    policy = policy_settings(object_readout=True, visual_head="none", goal="3d")
    torch.manual_seed(0)
    model = SequencePolicy(policy, 7, 16).eval()
    tokens, proprio, goal = inputs(policy)
    seq, readout = model.tokens(tokens, proprio, goal)
    assert seq.shape[1] == policy["window"] * 4  # joints, goal, read-out, action token per step
    fixed = readout.detach()
    # with the read-out's estimate held fixed, nothing else of the tokens reaches the actions
    # exact: the tokens reach nothing on this path, so the same operations run on the same numbers
    torch.testing.assert_close(model(tokens + 1.0, proprio, goal, readout_seen=fixed).actions,
                               model(tokens, proprio, goal, readout_seen=fixed).actions, rtol=0, atol=0)
    # derived: a +1 shift of every token moves the read-out by O(1), far above allclose's 1e-5 relative
    assert not torch.allclose(model(tokens + 1.0, proprio, goal).actions, model(tokens, proprio, goal).actions)


def test_visual_dropout_blanks_steps_in_training_only():
    policy = policy_settings(object_readout=True, visual_dropout=1.0, dropout=0.0)  # only the visual one random
    torch.manual_seed(0)
    model = SequencePolicy(policy, 7, 16)
    tokens, proprio, goal = inputs(policy)
    fixed = model.tokens(tokens, proprio, goal)[1].detach()
    model.train()
    # every step blanked: the visual tokens do not reach the actions (the read-out's estimate is held fixed)
    # exact: blanked tokens are replaced before any arithmetic, so the same operations run on the same numbers
    torch.testing.assert_close(model(tokens + 1.0, proprio, goal, readout_seen=fixed).actions,
                               model(tokens, proprio, goal, readout_seen=fixed).actions, rtol=0, atol=0)
    model.eval()  # evaluation sees every token
    # derived: a +1 shift of every token moves the actions by O(1), far above allclose's 1e-5 relative
    assert not torch.allclose(model(tokens + 1.0, proprio, goal, readout_seen=fixed).actions,
                              model(tokens, proprio, goal, readout_seen=fixed).actions)


@pytest.mark.parametrize("goal", ["2d", "3d"])
def test_goal_norm_standardizes_the_goal_in_training_and_in_the_checkpoint(tmp_path, goal):
    features, frames = write_stores(tmp_path)
    policy = policy_settings(goal=goal, goal_norm="zscore", epochs=1, save_every=1)
    d = data.load(policy, features, frames)
    train(policy, 0, features, frames, tmp_path / "run", progress=False)
    model, *_ = load_policy(tmp_path / "run" / "checkpoints" / "epoch_0001.pt")
    goals = d.labels.goal[d.train_frames]
    z = model.normalizer.goal(torch.from_numpy(goals))
    atol = zscore_atol(goals, model.normalizer.goal, z, stats_eps=EPS32)
    np.testing.assert_allclose(z.double().mean(0).numpy(), 0.0, rtol=0, atol=atol)  # derived: zscore_atol
    np.testing.assert_allclose(z.double().std(0, unbiased=False).numpy(), 1.0, rtol=0, atol=atol)  # derived: ^
    train(policy_settings(goal=goal, epochs=1, save_every=1), 0, features, frames, tmp_path / "plain",
          progress=False)
    plain, *_ = load_policy(tmp_path / "plain" / "checkpoints" / "epoch_0001.pt")
    raw = torch.from_numpy(d.labels.goal)
    assert torch.equal(plain.normalizer.goal(raw), raw)  # exact: goal_norm none passes the goal as given


def test_windows_pad_at_episode_edges():
    labels = Labels.from_offsets([0, 4, 10], np.zeros((10, 7)), np.zeros((10, 0)), np.zeros((10, 8)))
    frames = np.array([0, 1, 4, 9])
    assert window_frames(frames, labels, 3).tolist() == [[0, 0, 0], [0, 0, 1], [4, 4, 4], [7, 8, 9]]
    acts = action_frames(frames, labels, 3)
    assert acts.tolist() == [[0, 1, 2], [1, 2, 3], [4, 5, 6], [9, 9, 9]]
    np.testing.assert_array_equal(progress(acts, frames, labels)[3], [1, 1, 1])  # exact: 3 / 3 etc.
    # derived: k / 3 rounded to float32 (<= eps32 / 2 relative) against float64 thirds
    np.testing.assert_allclose(progress(acts, frames, labels)[0], [0, 1 / 3, 2 / 3], rtol=EPS32)


class ReadRecorder:
    """A tokens array that records every slice read from it."""

    def __init__(self, arr, chunk):
        self.arr, self.chunks, self.shape, self.reads = arr, (chunk,), arr.shape, []

    def __getitem__(self, s):
        self.reads.append((s.start, s.stop))
        return self.arr[s]


def test_loader_yields_each_window_once_per_epoch_one_chunk_at_a_time():
    N, chunk, T = 95, 32, 3
    tokens = np.arange(N, dtype=np.float32)[:, None, None, None] * np.ones((1, 2, 7, 4), np.float32)
    labels = Labels.from_offsets([0, 30, 55, 95], np.zeros((N, 7), np.float32), np.zeros((N, 0), np.float32),
                                 np.zeros((N, 8), np.float32))
    rec = ReadRecorder(tokens, chunk)
    loader = ChunkWindowLoader(rec, labels, T, 4, batch_size=10, cameras=[0, 1], seed=0)
    orders = []
    for epoch in range(2):
        seen = []
        for batch in loader.epoch(epoch):
            current = batch["tokens"][:, -1, 0, 0, 0].long()
            seen += current.tolist()
            # the window really is the T frames before the current one (clamped at the episode start)
            starts = torch.as_tensor(labels.start)[current]
            expect = torch.maximum(current[:, None] - torch.arange(T - 1, -1, -1), starts[:, None])
            assert torch.equal(batch["tokens"][:, :, 0, 0, 0].long(), expect)  # exact: frame indices
        assert sorted(seen) == list(range(N))
        orders.append(seen)
    assert orders[0] != orders[1]
    assert loader.max_chunks_in_ram == 1
    assert len(rec.reads) == 2 * 3 and max(hi - lo for lo, hi in rec.reads) <= chunk + T - 1  # exact: frame counts
    assert len(loader) == sum(-(-n // 10) for n in (32, 32, 31))
    again = ChunkWindowLoader(tokens, labels, T, 4, 10, [0, 1], seed=0, chunk_frames=chunk)
    assert [b["tokens"][:, -1, 0, 0, 0].long().tolist() for b in again.epoch(0)] != []
    assert sum((b["tokens"][:, -1, 0, 0, 0].long().tolist() for b in again.epoch(0)), []) == orders[0]


def test_every_step_windows_supervise_each_frame_once_an_epoch_from_about_a_tth_of_the_windows():
    N, chunk, T, H = 95, 32, 3, 4
    tokens = np.arange(N, dtype=np.float32)[:, None, None, None] * np.ones((1, 2, 7, 4), np.float32)
    action = np.zeros((N, 8), np.float32)
    action[:, 0] = np.arange(N)  # each frame's action names its frame
    offsets = [0, 30, 55, 95]
    labels = Labels.from_offsets(offsets, np.zeros((N, 7), np.float32), np.zeros((N, 0), np.float32), action,
                                 qpos=np.arange(N, dtype=np.float32)[:, None] * np.ones((1, 9), np.float32))
    loader = ChunkWindowLoader(ReadRecorder(tokens, chunk), labels, T, H, batch_size=4, cameras=[0, 1], seed=0,
                               every_step=True)
    current_frames = []
    for epoch in range(4):
        supervised, windows, batches = [], 0, 0
        for batch in loader.epoch(epoch):
            win = batch["tokens"][:, :, 0, 0, 0].long().numpy()
            assert batch["action"].shape == (len(win), T, H, 8) and batch["qpos"].shape == (len(win), T, 9)
            # every step's targets are its own frame's next H actions, relative to its own joints
            want = action_frames(win.reshape(-1), labels, H).reshape(len(win), T, H)
            np.testing.assert_array_equal(batch["action"][..., 0].numpy(), want)  # exact: frame ids
            np.testing.assert_array_equal(batch["qpos"][..., 0].numpy(), win)  # exact: frame ids
            supervised += win[batch["step_mask"].numpy()].tolist()
            windows += len(win)
            batches += 1
            current_frames.append(tuple(sorted(win[:, -1])))
        assert sorted(supervised) == list(range(N))  # each frame once, none twice
        assert batches == loader.batches(epoch)
        # ceil(L / T) to ceil((L + T - 1) / T) windows an episode of L frames, against N for last_step
        lengths = np.diff(offsets)
        assert sum(-(-n // T) for n in lengths) <= windows <= sum(-(-(n + T - 1) // T) for n in lengths)
    assert len(set(current_frames)) > 1  # the grid's phase moves between epochs


@pytest.mark.parametrize("window", [1, 5])
def test_every_step_actions_end_with_the_current_steps(window):
    policy = policy_settings(window=window, goal="2d", dropout=0.0)
    torch.manual_seed(0)
    model = SequencePolicy(policy, 7, 16).eval().double()
    x = inputs(policy, dtype=torch.float64)
    every = model(*x, every_step=True).actions
    assert every.shape == (3, window, policy["horizon"], 8)
    states = model.action_states(model.tokens(*x)[0])  # every step's action token, through the whole decoder
    last = model.action_head(states[:, -1])
    # the largest term of any of the head's sums: each Linear's largest weight times its largest input
    h, term = states.detach(), 0.0
    for layer in model.action_head.net:
        if isinstance(layer, torch.nn.Linear):
            term = max(term, float(layer.weight.detach().abs().max() * h.abs().max()))
        h = layer(h)
    W = policy["width"]
    # derived: float64, the same row-wise MLP on 3 rows or on 3 * T: at most its 3 sums of W terms reordered
    torch.testing.assert_close(every[:, -1], last, rtol=0, atol=reduction_atol(W, term, depth=3))
    # and that last state is the one the closed loop reads (test_the_current_action_state_is_the_full_...)
    assert not torch.allclose(every[:, 0], last, rtol=0, atol=1e-3) or window == 1  # derived: O(1) apart


def test_an_every_step_policy_trains_through_its_schedule_and_resumes_identically(tmp_path):
    features, frames = write_stores(tmp_path)
    policy = policy_settings(action_loss="every_step", lr_schedule="cosine", batch_size=4)
    full = train(policy, 0, features, frames, tmp_path / "full", progress=False)
    lrs = full["lr"].to_list()  # epochs of different lengths, one schedule: the warm-up's peak, then down to ~0
    assert lrs[0] == policy["lr"] and lrs == sorted(lrs, reverse=True) and lrs[-1] < policy["lr"] / 10
    assert full["loss"][-1] < full["loss"][0]
    with pytest.raises(RuntimeError):
        train(policy, 0, features, frames, tmp_path / "resumed", progress=False,
              on_epoch_end=lambda e: (_ for _ in ()).throw(RuntimeError("killed")) if e == 2 else None)
    resumed = train(policy, 0, features, frames, tmp_path / "resumed", progress=False)
    assert resumed.drop("seconds").equals(full.drop("seconds"))  # one-cpu: two trainings' losses
    _, settings, _ = load_policy(tmp_path / "full" / "checkpoints" / "epoch_0004.pt")
    assert settings.training.action_loss == "every_step"


def test_training_writes_checkpoints_and_log_and_a_killed_run_resumes_identically(tmp_path):
    features, frames = write_stores(tmp_path)
    # cosine: a resumed run must rejoin the schedule where the killed one left it, with no scheduler state saved
    policy = policy_settings(loss_weighting="u_shaped", lr_schedule="cosine")
    full = train(policy, 0, features, frames, tmp_path / "full", progress=False)
    assert full["epoch"].to_list() == [1, 2, 3, 4]
    lrs = full["lr"].to_list()  # each epoch's last step: the warm-up's peak, then falling
    assert lrs[0] == policy["lr"] and lrs == sorted(lrs, reverse=True) and lrs[-1] < policy["lr"] / 10
    assert set(full.columns) == {"epoch", "loss", "loss_joints", "loss_gripper", "loss_aux", "loss_readout", "lr",
                                 "seconds"}
    assert full["loss"][-1] < full["loss"][0]
    ckpts = sorted(p.name for p in (tmp_path / "full" / "checkpoints").iterdir())
    assert ckpts == ["epoch_0002.pt", "epoch_0004.pt"]
    assert not (tmp_path / "full" / ".train").exists()

    class Killed(Exception):
        pass

    def kill_after_3(epoch):
        if epoch == 3:
            raise Killed

    with pytest.raises(Killed):
        train(policy, 0, features, frames, tmp_path / "resumed", progress=False, on_epoch_end=kill_after_3)
    assert not (tmp_path / "resumed" / "train_log.parquet").exists()
    resumed = train(policy, 0, features, frames, tmp_path / "resumed", progress=False)
    assert resumed.drop("seconds").equals(full.drop("seconds"))  # one-cpu: two trainings' losses
    a = torch.load(tmp_path / "full" / "checkpoints" / "epoch_0004.pt", weights_only=False)
    b = torch.load(tmp_path / "resumed" / "checkpoints" / "epoch_0004.pt", weights_only=False)
    for k in a["model"]:
        # one-cpu: both trainings ran here, so the same kernels; another CPU kind would give other bits to both
        assert torch.equal(a["model"][k], b["model"][k]), k
    assert pl.read_parquet(tmp_path / "resumed" / "train_log.parquet")["epoch"].to_list() == [1, 2, 3, 4]

    model, settings, meta = load_policy(tmp_path / "full" / "checkpoints" / "epoch_0004.pt")
    assert settings == PolicySettings.of(policy) and meta["K"] == 7 and model.normalizer.action.std.shape == (8,)
    assert not model.training
    # the trainable parameters, recorded at training time: fewer than the state dict's numbers, which also hold the
    # Normalizer's statistics
    trainable = sum(p.numel() for p in model.parameters() if p.requires_grad)
    assert a["parameters"] == trainable < sum(v.numel() for v in a["model"].values())


def test_changed_settings_discard_a_stale_resume_state(tmp_path):
    features, frames = write_stores(tmp_path)
    with pytest.raises(RuntimeError):
        train(policy_settings(), 0, features, frames, tmp_path / "run", progress=False,
              on_epoch_end=lambda e: (_ for _ in ()).throw(RuntimeError("killed")))
    table = train(policy_settings(epochs=2, save_every=1), 0, features, frames, tmp_path / "run", progress=False)
    assert table["epoch"].to_list() == [1, 2]


def test_policy_settings_name_an_unknown_or_missing_key_and_fill_later_levers():
    base = policy_settings()
    assert PolicySettings.of(base).as_dict() == {**PolicySettings.of(base).as_dict(), **base}
    with pytest.raises(ValueError, match="unknown key.*'widht'"):
        PolicySettings.of({**base, "widht": 3})
    with pytest.raises(ValueError, match="missing key.*'window'"):
        PolicySettings.of({k: v for k, v in base.items() if k != "window"})
    old = {k: v for k, v in base.items() if k != "object_readout"}
    assert PolicySettings.of(old).readout.enabled is False  # a checkpoint from before the key: trained without it
    # a retired lever: a checkpoint that names it switched off loads, one trained with it on is refused
    assert PolicySettings.of({**base, "first_frame": False}) == PolicySettings.of(base)
    with pytest.raises(ValueError, match=r"\['first_frame'\] are retired levers \(last in commit"):
        PolicySettings.of({**base, "first_frame": True})


@pytest.mark.parametrize("goal,calibration", [("3d", "exact"), ("2d", "exact"), ("2d", "approx")])
def test_goal_relative_adds_the_goal_minus_the_tcp_as_the_closed_loop_computes_it(tmp_path, default_config, goal,
                                                                                   calibration):
    from ocpipe.frames.store import open_store
    from ocpipe.sim import envs, projection

    features, frames_path = write_stores(tmp_path)
    policy = PolicySettings.of(policy_settings(goal=goal, goal_calibration=calibration, goal_relative="tcp"))
    frames = open_store(frames_path)
    approx = default_config["camera_approx"]
    cams = observation.store_cameras(policy, frames, approx)
    labels = {k: frames[k][:] for k in ("qpos", "goal_pos", "tcp_pos")}
    plain = observation.goal(PolicySettings.of({**policy.as_dict(), "goal_relative": "none"}), labels, cams)
    rel = observation.goal(policy, labels, cams)
    G = plain.shape[1]
    assert rel.shape == (len(plain), 2 * G)
    np.testing.assert_array_equal(rel[:, :G], plain)  # exact: the same code, its columns kept
    tcp = labels["tcp_pos"]
    if goal == "3d":
        np.testing.assert_array_equal(rel[:, G:], labels["goal_pos"] - tcp)  # exact: one float32 subtraction
    else:  # the TCP goes through the goal's own camera model
        if calibration == "exact":
            # exact: the store's own projection, the same float64 code on the same float32 inputs
            np.testing.assert_array_equal(plain, frames["goal2d_exact"][:])
        # derived: image fractions in [0, 1]; the product rounds once to float32 after the float64 difference, the
        # expected side rounds the goal's projection once before it (<= eps32 / 2 each)
        np.testing.assert_allclose(rel[:, G:], plain - projection.goal2d(tcp, *cams, 64), rtol=0, atol=EPS32)
    assert np.ptp(rel[:, G:] - rel[:, :G], axis=0).min() > 0.01  # the hand moves: not the goal in disguise
    # one simulator step gives the same input from its goal, TCP and camera parameters
    K, E = frames["cam_intrinsic"][:], frames["cam_extrinsic"][:]
    obs = {"sensor_param": {u: {"intrinsic_cv": torch.from_numpy(K[i])[None],
                                "extrinsic_cv": torch.from_numpy(E[i])[None]} for i, u in enumerate(["b", "s"])}}
    step_cams = observation.step_cameras(policy, obs, ["b", "s"],
                                         envs.approx_camera_matrices(default_config, ["base", "side"], 64))
    for i in (0, 17, 60):
        step = {k: v[i : i + 1] for k, v in labels.items()}
        # derived: one row against the batch: the same float64 arithmetic per row, whose vector and scalar loops may
        # differ by a float64 ulp, which can move the float32 result by one of its ulps (values under 1)
        np.testing.assert_allclose(observation.goal(policy, step, step_cams)[0], rel[i], rtol=0, atol=EPS32)
    if calibration == "approx":
        with pytest.raises(ValueError, match="camera_approx"):
            observation.store_cameras(policy, frames, None)
    # the model takes the wider goal, and training runs end to end
    model = SequencePolicy(policy, 7, 16)
    tokens, proprio, _ = inputs(policy.as_dict())
    out = model(tokens, proprio, torch.randn(3, policy.network.window, 2 * G))
    assert out.actions.shape == (3, policy.network.horizon, 8)
    train(policy, 0, features, frames_path, tmp_path / "run", progress=False, camera_approx=approx)
    _, saved, _ = load_policy(tmp_path / "run" / "checkpoints" / f"epoch_{policy.training.epochs:04d}.pt")
    assert saved.goal.relative == "tcp"


def test_the_cosine_schedule_warms_up_over_one_epoch_then_decays_towards_zero():
    from ocpipe.policy.training import learning_rate

    tr = PolicySettings.of(policy_settings(epochs=5, lr_schedule="cosine")).training
    steps = [learning_rate(tr, s, 10) for s in range(50)]
    # exact: (s + 1) / 10 of lr, the same product the code forms
    assert steps[:10] == [tr.lr * (s + 1) / 10 for s in range(10)]
    assert steps[10] == tr.lr  # cos(0): the decay starts at the peak
    assert all(a > b for a, b in zip(steps[10:], steps[11:], strict=False)) and steps[-1] < tr.lr / 100
    constant = PolicySettings.of(policy_settings(lr_schedule="constant")).training
    assert {learning_rate(constant, s, 10) for s in range(50)} == {constant.lr}
