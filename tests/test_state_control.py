"""The privileged-state control sees the same tokens in training (frames store, from replay) and in evaluation
(read from the simulator, nothing rendered), on a real episode; so does a joints7_tcp policy its TCP input."""

import h5py
import numpy as np
import torch
from tolerances import EPS32, reduction_atol

from ocpipe.encoders.state import StateEncoder, state_tokens
from ocpipe.frames.replay import Replayer
from ocpipe.sim import envs


def _save_states(group, states: dict, prefix=""):
    for k, v in states.items():
        if isinstance(v, dict):
            _save_states(group, v, f"{prefix}{k}/")
        else:
            group[f"{prefix}{k}"] = np.stack(v)


def _stack(acc: dict, state: dict) -> None:
    for k, v in state.items():
        if isinstance(v, dict):
            _stack(acc.setdefault(k, {}), v)
        else:
            acc.setdefault(k, []).append(v[0].cpu().numpy())


def test_training_and_evaluation_tokens_agree_on_a_replayed_episode(tmp_path, default_config):
    seed, steps = 10_003, 12
    # evaluation side: the env the control runs in (no camera), tokens from the simulator's readouts
    env = envs.make_env("PickCube-v1", default_config, None)
    env.reset(seed=seed)
    rng = np.random.default_rng(0)
    relative = StateEncoder(tcp_relative=True)
    states, actions, eval_tokens, eval_relative, eval_tcp = {}, [], [], [], []
    for t in range(steps + 1):
        _stack(states, env.unwrapped.get_state_dict())
        r = envs.task_readouts(env)
        if t == steps:
            break
        eval_tokens.append(state_tokens(r["obj_pos"], r["obj_quat"]))
        eval_relative.append(relative.tokens_from_labels(r))  # what the closed loop feeds a tcp_relative control
        eval_tcp.append(r["tcp_pos"])  # what a joints7_tcp policy reads in evaluation
        action = np.concatenate([r["qpos"][:7] + rng.normal(0, 0.05, 7), [1.0 if t > 6 else -1.0]]).astype(np.float32)
        actions.append(action)
        env.step(torch.as_tensor(action[None]))
    env.close()

    # training side: that episode replayed with env-state alignment, labels as the frames store records them
    h5_path = tmp_path / "demo.h5"
    with h5py.File(h5_path, "w") as f:
        g = f.create_group("traj_0")
        g["actions"] = np.stack(actions)
        _save_states(g.create_group("env_states"), states)
    replayer = Replayer("PickCube-v1", default_config, "dual", 32)
    try:
        with h5py.File(h5_path) as f:
            ep = replayer.replay(f, {"episode_id": 0, "episode_seed": seed, "reset_kwargs": {"seed": seed}})
    finally:
        replayer.close()
    train_tokens = state_tokens(ep.arrays["obj_pos"], ep.arrays["obj_quat"])
    assert train_tokens.shape == (steps, 1, 1, 5)
    # derived: the replay sets the recorded float32 pose and reads it back; the tokens' float64 arctan2, sin and cos
    # run over the episode at once against one step at a time, whose vector and scalar loops may differ by a float64
    # ulp, which can move the float32 token by one of its ulps (values under 1)
    np.testing.assert_allclose(train_tokens, np.stack(eval_tokens), rtol=0, atol=EPS32)
    chain_atol = reduction_atol(3, 1.0, depth=9, eps=EPS32)
    # derived: the replay's TCP is PhysX's float32 kinematics of the recorded joints, evaluation's the step's own:
    # two computations of one pose, each 9 chained rigid transforms (3-term sums) of sizes under 1 m
    np.testing.assert_allclose(ep.arrays["tcp_pos"], np.stack(eval_tcp), rtol=0, atol=chain_atol)
    # the TCP-relative token, as the features stage makes it from the frames store's arrays
    train_relative = state_tokens(ep.arrays["obj_pos"], ep.arrays["obj_quat"], ep.arrays["tcp_pos"])
    assert train_relative.shape == (steps, 1, 1, relative.dims) == (steps, 1, 1, 8)
    # derived: the object's part exact as the first check, the TCP's as the second, one float32 subtraction more
    np.testing.assert_allclose(train_relative, np.stack(eval_relative), rtol=0, atol=chain_atol + EPS32)
    # and the arm moved, so the offset from the TCP is not the object's position in disguise
    assert np.ptp(train_relative[:, 0, 0, 5:] - train_relative[:, 0, 0, :3], axis=0).max() > 0.01
