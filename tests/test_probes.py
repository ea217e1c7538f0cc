import numpy as np
import pytest

from ocpipe.features import probes


def _store(rng, episodes=20, frames=40, informative=True):
    """Per-frame tokens (N, 2, 7, 4) and positions; ``informative``: three token dims hold the position (x10)
    with 2 mm of noise, the rest is noise; else every dim is noise independent of the positions."""
    N = episodes * frames
    episode_index = np.repeat(np.arange(episodes), frames)
    pos = rng.uniform(-0.1, 0.1, (N, 3)) + [0, 0, 0.02]
    tokens = rng.normal(size=(N, 2, 7, 4))
    if informative:
        tokens.reshape(N, -1)[:, :3] = pos * 10 + rng.normal(scale=0.002 * 10, size=(N, 3))
    return tokens.astype(np.float32), pos, episode_index


def test_episode_split_holds_out_whole_last_episodes():
    ep = np.repeat(np.arange(10), 5)
    train, test = probes.episode_split(ep, 0.15)
    assert set(ep[test]) == {8, 9} and set(ep[train]) == set(range(8))  # round(1.5) -> 2 episodes
    with pytest.raises(ValueError, match="at least 2 episodes"):
        probes.episode_split(np.zeros(5, int), 0.15)


def test_probes_recover_a_position_the_tokens_hold():
    tokens, pos, ep = _store(np.random.default_rng(0))
    out = probes.probe(tokens, {"obj_pos": pos}, ep, holdout=0.2, seed=0, mlp_epochs=40)
    assert out["test_episodes"] == 4 and out["test_frames"] == 160
    res = out["obj_pos"]
    # the 3D noise of 2 mm per axis has a median norm of ~3.1 mm: ridge should be there, the mean far off
    assert res["ridge"]["median_cm"] < 0.5 < 5 < res["mean"]["median_cm"]
    assert res["mlp"]["median_cm"] < 2.0


def test_probes_do_not_beat_the_mean_on_uninformative_tokens():
    tokens, pos, ep = _store(np.random.default_rng(1), informative=False)
    res = probes.probe(tokens, {"obj_pos": pos}, ep, holdout=0.2, seed=0, mlp_epochs=0)["obj_pos"]
    assert "mlp" not in res
    assert res["ridge"]["median_cm"] > 0.9 * res["mean"]["median_cm"]


def test_mlp_probe_is_seeded():
    tokens, pos, ep = _store(np.random.default_rng(2), episodes=6, frames=20)
    a = probes.probe(tokens, {"obj_pos": pos}, ep, seed=3, mlp_epochs=3)
    b = probes.probe(tokens, {"obj_pos": pos}, ep, seed=3, mlp_epochs=3)
    assert a == b


def test_first_frame_probe_scores_only_each_held_out_episodes_first_frame():
    """Tokens that hold the position on every frame but the first of each episode (as when a probe can read the
    object off the gripper that reached it): the all-frames error stays small, the first-frames error does not."""
    rng = np.random.default_rng(4)
    tokens, pos, ep = _store(rng)
    first = np.r_[True, ep[1:] != ep[:-1]]
    tokens[first] = rng.normal(size=tokens[first].shape)
    res = probes.probe(tokens, {"obj_pos": pos}, ep, holdout=0.2, seed=0, mlp_epochs=0)["obj_pos"]
    assert res["ridge"]["median_cm"] < 2.0 < res["mean"]["median_cm"] < res["first_frames"]["ridge"]["median_cm"]
    tokens, pos, ep = _store(np.random.default_rng(4))
    clean = probes.probe(tokens, {"obj_pos": pos}, ep, holdout=0.2, seed=0, mlp_epochs=0)
    assert clean["obj_pos"]["first_frames"]["ridge"]["median_cm"] < 0.5


def test_fit_mse_ignores_an_output_column_weighted_zero():
    torch = pytest.importorskip("torch")
    x = torch.randn(200, 4, generator=torch.Generator().manual_seed(0))
    y = torch.stack([x[:, 0] * 2, torch.zeros(200)], 1)
    noisy = y.clone()
    noisy[:, 1] = 100 * torch.randn(200, generator=torch.Generator().manual_seed(1))
    nets = []
    for target, w in ((y, None), (noisy, torch.tensor([1.0, 0.0])), (y, torch.tensor([1.0, 0.0]))):
        torch.manual_seed(0)
        net = torch.nn.Linear(4, 2)
        probes.fit_mse(net, x, target, torch.Generator().manual_seed(0), epochs=5, batch=32, weights=w)
        nets.append(net.weight.detach().clone())
    # the zero-weighted column's targets do not matter
    # one-cpu: a weight of exactly 0 zeroes that column's loss and gradient, so both fits run the same float32 ops on
    # the same values in this process; the bits themselves follow the CPU's kernels
    assert torch.equal(nets[1], nets[2])
    # and unweighted, they do: the second row trains toward 0 instead of staying at its initial value
    # derived: AdamW moves each weight by ~lr = 1e-3 per step over 35 steps, an O(1e-2) change on weights of size
    # <= 1, far above allclose's rtol 1e-5 (round-off alone is ~1e-7)
    assert not torch.allclose(nets[0], nets[2])
