"""Linear and MLP probes: how well does a frozen token set encode where things are?

A probe regresses a 3D position (the cube, the goal marker, the gripper's TCP) from the flattened tokens of one
frame (every camera, every slot). It is fitted on the store's first episodes and scored on the last ones (whole
episodes held out, so neighbouring frames of one episode never sit on both sides), in centimetres, beside the
error of always answering the training mean. A token set a policy is meant to act on should place the cube to
about a centimetre; a probe that cannot beat the mean by much says the encoder, not the policy, is the problem."""

from __future__ import annotations

import numpy as np

TARGETS = ("obj_pos", "goal_pos", "tcp_pos")


def episode_split(episode_index: np.ndarray, holdout: float) -> tuple[np.ndarray, np.ndarray]:
    """Boolean (train, test) masks over frames: the last ``holdout`` share of episodes (at least one) is test."""
    episodes = np.unique(episode_index)
    if len(episodes) < 2:
        raise ValueError(f"a probe needs at least 2 episodes to hold one out, the store has {len(episodes)}")
    n_test = min(len(episodes) - 1, max(1, int(round(holdout * len(episodes)))))
    test = np.isin(episode_index, episodes[-n_test:])
    return ~test, test


def _standardize(x_train: np.ndarray, x: np.ndarray) -> np.ndarray:
    mean, std = x_train.mean(0), x_train.std(0) + 1e-6
    return (x - mean) / std


def ridge(x_train: np.ndarray, y_train: np.ndarray, x_test: np.ndarray, alpha: float = 1e-3) -> np.ndarray:
    """Ridge regression on standardized inputs (closed form); ``alpha`` is per training frame."""
    xs = _standardize(x_train, np.concatenate([x_train, x_test])).astype(np.float64)
    a, b = xs[: len(x_train)], xs[len(x_train):]
    a1, b1 = np.c_[a, np.ones(len(a))], np.c_[b, np.ones(len(b))]
    reg = alpha * len(a) * np.eye(a1.shape[1])
    reg[-1, -1] = 0.0  # no penalty on the intercept
    w = np.linalg.solve(a1.T @ a1 + reg, a1.T @ y_train.astype(np.float64))
    return b1 @ w


def mlp(x_train: np.ndarray, y_train: np.ndarray, x_test: np.ndarray, seed: int, hidden: int = 256,
        epochs: int = 150, batch: int = 256, lr: float = 1e-3) -> np.ndarray:
    """A 2-hidden-layer MLP on standardized inputs and outputs (Adam, cosine schedule, seeded)."""
    import torch  # here, not at the top: `ocpipe summary` reads probes.TARGETS without loading torch

    gen = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    xs = torch.as_tensor(_standardize(x_train, np.concatenate([x_train, x_test])), dtype=torch.float32)
    a, b = xs[: len(x_train)], xs[len(x_train):]
    y_mean, y_std = y_train.mean(0), y_train.std(0) + 1e-6
    y = torch.as_tensor((y_train - y_mean) / y_std, dtype=torch.float32)
    net = torch.nn.Sequential(torch.nn.Linear(a.shape[1], hidden), torch.nn.GELU(), torch.nn.Linear(hidden, hidden),
                              torch.nn.GELU(), torch.nn.Linear(hidden, y.shape[1]))
    fit_mse(net, a, y, gen, epochs, batch, lr)
    with torch.no_grad():
        return net(b).numpy() * y_std + y_mean


def fit_mse(net, x, y, generator, epochs: int, batch: int = 256, lr: float = 1e-3, weights=None) -> float:
    """Fit ``net`` to (x, y) tensors by mean squared error (each output column weighted by ``weights``, default 1):
    AdamW (weight decay 1e-4), cosine decay over all steps, batches shuffled by ``generator``. Shared by the probes
    and the policy's object read-out. -> the last loss."""
    import torch

    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs * max(1, -(-len(x) // batch)))
    loss = torch.zeros(())
    for _ in range(epochs):
        for idx in torch.randperm(len(x), generator=generator).split(batch):
            err = (net(x[idx]) - y[idx]) ** 2
            loss = (err * weights).mean() if weights is not None else err.mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
    return loss.item()


def error_cm(pred: np.ndarray, truth: np.ndarray) -> dict:
    err = np.linalg.norm(pred - truth, axis=-1) * 100.0
    return {"median_cm": round(float(np.median(err)), 2), "p90_cm": round(float(np.quantile(err, 0.9)), 2)}


def probe(tokens: np.ndarray, targets: dict[str, np.ndarray], episode_index: np.ndarray, holdout: float = 0.15,
          seed: int = 0, mlp_epochs: int = 150) -> dict:
    """``tokens`` (N, ...) per frame; ``targets`` name -> (N, 3) positions in metres.

    -> {"train_frames", "test_frames", "test_episodes", name: {"mean": {...}, "ridge": {...}, "mlp": {...},
    "first_frames": {"ridge": {...}, "mlp": {...}}}}, errors in cm on the held-out episodes; "first_frames" scores
    only each held-out episode's first frame, where the arm is still far from the object: over all frames a probe
    can place the object by the gripper that holds or approaches it, on first frames only by the object itself."""
    x = tokens.reshape(len(tokens), -1).astype(np.float32)
    train, test = episode_split(episode_index, holdout)
    out = {"train_frames": int(train.sum()), "test_frames": int(test.sum()),
           "test_episodes": int(len(np.unique(episode_index[test]))), "holdout": holdout}
    ys = {name: np.asarray(y, dtype=np.float64) for name, y in targets.items()}
    # one MLP for every target at once: the probe asks what the tokens hold, not how well 3 nets can be tuned
    joint = (mlp(x[train], np.concatenate([y[train] for y in ys.values()], 1), x[test], seed, epochs=mlp_epochs)
             if mlp_epochs > 0 and ys else None)
    starts = np.r_[True, episode_index[1:] != episode_index[:-1]][test]  # first frames among the test frames
    for i, (name, y) in enumerate(ys.items()):
        baseline = np.broadcast_to(y[train].mean(0), y[test].shape)
        pred = {"ridge": ridge(x[train], y[train], x[test])}
        if joint is not None:
            pred["mlp"] = joint[:, 3 * i: 3 * i + 3]
        out[name] = {"mean": error_cm(baseline, y[test]), **{k: error_cm(p, y[test]) for k, p in pred.items()},
                     "first_frames": {k: error_cm(p[starts], y[test][starts]) for k, p in pred.items()}}
    return out
