"""Policy-training benchmarks (issue 4): the chunk-aware loader vs a plain shuffled random-access loader, and
seconds per training epoch at the thesis' model width vs the default profile's.

    .venv/bin/python bench/bench_policy.py                       # on the default build's stores
    .venv/bin/python bench/bench_policy.py --synthetic 20000     # on a synthetic thesis-shaped store (7 x 256)
    .venv/bin/python bench/bench_policy.py --decoder --threads 1 # a training step: whole decoder vs last token only
    .venv/bin/python bench/bench_policy.py --per-policy goal2d "goal2d:epochs=10,save_every=5,lr_schedule=cosine"
        # CPU-seconds to train one policy end to end, per recipe, against the first, and against the floor: the same
        # model's forward, backward and step on random tensors already in memory, for the recipe's steps
    .venv/bin/python bench/bench_policy.py --step-kernels --threads 1
        # that step in eager mode (as training runs), under torch.compile, under bfloat16 autocast, and one policy's
        # share of a step that trains five policies together (torch.func.vmap)

Each loader runs in its own process so its peak RSS is its own."""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from ocpipe.config import experiments  # noqa: E402
from ocpipe.config import validate as cfgmod  # noqa: E402
from ocpipe.policy import data  # noqa: E402
from ocpipe.policy.windows import ChunkWindowLoader, make_batch  # noqa: E402


class RandomAccessWindows(torch.utils.data.Dataset):
    """The baseline: one sample = one read of its T frames straight from the Zarr store."""

    def __init__(self, tokens, labels, T, H, cameras):
        self.tokens, self.labels, self.T, self.H, self.cameras = tokens, labels, T, H, cameras

    def __len__(self):
        return self.tokens.shape[0]

    def __getitem__(self, i):
        lo = max(int(self.labels.start[i]), i - self.T + 1)
        block = np.asarray(self.tokens[lo : i + 1])
        b = make_batch(block, lo, np.array([i]), self.labels, self.T, self.H, self.cameras)
        return {k: v[0] for k, v in b.items()}


def _loader_worker(kind, policy, features, frames, max_batches, queue, camera_approx):
    torch.set_num_threads(1)
    d = data.load(policy, features, frames, camera_approx)
    tokens, labels = d.tokens, d.labels
    if kind == "chunk-aware":
        it = ChunkWindowLoader(tokens, labels, policy["window"], policy["horizon"], policy["batch_size"],
                               policy["cameras"], seed=0).epoch(0)
    else:
        ds = RandomAccessWindows(tokens, labels, policy["window"], policy["horizon"], policy["cameras"])
        it = iter(torch.utils.data.DataLoader(ds, batch_size=policy["batch_size"], shuffle=True,
                                              generator=torch.Generator().manual_seed(0)))
    n, t0 = 0, time.perf_counter()
    for b, batch in enumerate(it):
        n += len(batch["action"])
        if max_batches and b + 1 >= max_batches:
            break
    seconds = time.perf_counter() - t0
    queue.put(
        {"samples": n, "seconds": seconds, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    )


def measure_loader(kind, policy, features, frames, max_batches, camera_approx):
    queue = mp.get_context("spawn").Queue()
    proc = mp.get_context("spawn").Process(
        target=_loader_worker, args=(kind, policy, features, frames, max_batches, queue, camera_approx)
    )
    proc.start()
    out = queue.get()
    proc.join()
    return out


def seconds_per_epoch(policy, features, frames, max_batches, threads, camera_approx):
    from ocpipe.policy import readout
    from ocpipe.policy.model import SequencePolicy
    from ocpipe.policy.settings import PolicySettings
    from ocpipe.policy.training import batch_loss

    torch.set_num_threads(threads)
    settings = PolicySettings.of(policy)
    d = data.load(policy, features, frames, camera_approx)
    tokens, labels, meta = d.tokens, d.labels, d.meta
    loader = ChunkWindowLoader(tokens, labels, policy["window"], policy["horizon"], policy["batch_size"],
                               policy["cameras"], seed=0, every_step=policy["action_loss"] == "every_step")
    torch.manual_seed(0)
    model = SequencePolicy(policy, meta["K"], meta["D"])
    opt = torch.optim.AdamW(model.parameters(), lr=policy["lr"])
    readout_w = readout.readout_weights(settings.readout.yaw_weight, "cpu")
    n, t0 = 0, time.perf_counter()
    for _, batch in enumerate(loader.epoch(0)):
        loss = batch_loss(model, settings, batch, 0, readout_w)["loss"]  # the training loop's loss, every term
        opt.zero_grad()
        loss.backward()
        opt.step()
        n += 1
        if max_batches and n >= max_batches:
            break
    per_batch = (time.perf_counter() - t0) / n
    return per_batch * len(loader), n, len(loader), sum(p.numel() for p in model.parameters())


def time_decoder(policy, steps: int, threads: int, K: int = 7, D: int = 64) -> None:
    """A training step (forward, backward, AdamW) of ``policy``'s model on random batches of its shapes, with the
    whole decoder's output (every token, the last one read) against the last layer run for the last token alone
    (SequencePolicy.current_action_state), alternating so both see the same machine load."""
    from ocpipe.policy.model import PROPRIO_DIMS, SequencePolicy, goal_dims
    from ocpipe.policy.settings import PolicySettings

    torch.set_num_threads(threads)
    settings = PolicySettings.of(policy)
    B, T, C = policy["batch_size"], policy["window"], len(policy["cameras"])
    g = torch.Generator().manual_seed(0)
    batch = (torch.randn(B, T, C, K, D, generator=g), torch.randn(B, T, PROPRIO_DIMS[settings.network.proprio],
             generator=g), torch.randn(B, T, goal_dims(settings), generator=g))
    torch.manual_seed(0)
    model = SequencePolicy(policy, K, D)
    opt = torch.optim.AdamW(model.parameters(), lr=policy["lr"])
    paths = {"whole decoder": lambda seq: model.action_states(seq)[:, -1],
             "last token only": model.current_action_state}
    seconds = dict.fromkeys(paths, 0.0)
    for _ in range(steps):
        for name, state in paths.items():
            t0 = time.perf_counter()
            act = state(model.tokens(*batch)[0])
            loss = model.action_head(act).square().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            seconds[name] += time.perf_counter() - t0
    print(f"training step, batch {B}, T {T}, width {policy['width']}, {policy['layers']} layers, {threads} threads, "
          f"{steps} steps each:")
    for name, sec in seconds.items():
        print(f"  {name:<16}{sec / steps * 1000:>8.1f} ms")
    a, b = seconds.values()
    print(f"  ratio whole / last token only: {a / b:.2f}x\n")


def _train_worker(policy, stores, threads, camera_approx, queue):
    from ocpipe.policy import training

    with tempfile.TemporaryDirectory() as out:
        t0 = time.process_time()
        log = training.train(policy, 0, stores["features"], stores["frames"], Path(out) / "run", threads=threads,
                             progress=False, scenes_path=stores.get("scenes"), camera_approx=camera_approx)
        queue.put({"cpu": time.process_time() - t0, "epochs": len(log)})


STACKED = 5  # policies trained together in the 'stacked' variant: a row's replicates
# how the floor's step runs: the training loop's eager kernels, or a candidate that changes only the arithmetic
KERNELS = {
    "eager": "eager (as training runs)",
    "compile": "torch.compile (inductor)",
    "bf16": "bfloat16 autocast",
    "stacked": f"{STACKED} policies stacked (vmap)",
}


def _floor_worker(policy, steps, threads, K, D, kernel, queue):
    """The model's forward, backward, clipping and AdamW step on random batches already in memory, timed over a
    sample of steps (after 3 untimed ones, which hold torch.compile's compilation) and scaled to ``steps``; for
    'stacked', the CPU of one policy's share of a step that trains STACKED policies together."""
    from ocpipe.policy.model import PROPRIO_DIMS, goal_dims
    from ocpipe.policy.settings import PolicySettings

    torch.set_num_threads(threads)
    settings = PolicySettings.of(policy)
    B, T, C = policy["batch_size"], policy["window"], len(policy["cameras"])
    lead = (STACKED,) if kernel == "stacked" else ()  # each stacked policy its own batch
    g = torch.Generator().manual_seed(0)
    batch = (torch.randn(*lead, B, T, C, K, D, generator=g),
             torch.randn(*lead, B, T, PROPRIO_DIMS[settings.network.proprio], generator=g),
             torch.randn(*lead, B, T, goal_dims(settings), generator=g))
    step = (_stacked_step if kernel == "stacked" else _single_step)(policy, K, D, kernel, batch)
    for _ in range(3):
        step()
    timed = min(steps, 200)
    t0 = time.process_time()
    for _ in range(timed):
        step()
    queue.put((time.process_time() - t0) / timed * steps / (STACKED if kernel == "stacked" else 1))


def _single_step(policy, K, D, kernel, batch):
    from ocpipe.policy.model import SequencePolicy

    torch.manual_seed(0)
    model = SequencePolicy(policy, K, D)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=policy["lr"])
    forward = torch.compile(model) if kernel == "compile" else model
    every_step = policy["action_loss"] == "every_step"  # the whole decoder, every step's actions

    def step():
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=kernel == "bf16"):
            loss = forward(*batch, every_step=every_step).actions.float().square().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()

    return step


def _stacked_step(policy, K, D, kernel, batch):
    """STACKED policies' parameters stacked along a new first dimension, their forward passes as one under
    torch.func.vmap (each its own dropout draws), one AdamW over the stacks (element-wise, so the same as one per
    policy) and each policy's gradient clipped by its own norm."""
    import copy

    from torch.func import functional_call, stack_module_state, vmap

    from ocpipe.policy.model import SequencePolicy

    models = []
    for seed in range(STACKED):
        torch.manual_seed(seed)
        models.append(SequencePolicy(policy, K, D))
    params, buffers = stack_module_state(models)
    params = {k: v for k, v in params.items() if v.requires_grad}
    skeleton = copy.deepcopy(models[0]).to("meta")
    opt = torch.optim.AdamW(list(params.values()), lr=policy["lr"])

    every_step = {"every_step": policy["action_loss"] == "every_step"}

    def loss_of(p, b, *x):
        return functional_call(skeleton, (p, b), x, every_step, strict=False).actions.square().mean()

    losses = vmap(loss_of, randomness="different")

    def step():
        loss = losses(params, buffers, *batch).sum()  # each policy's gradient is its own loss's
        opt.zero_grad(set_to_none=True)
        loss.backward()
        grads = [p.grad for p in params.values() if p.grad is not None]
        norms = torch.stack([gr.flatten(1).square().sum(1) for gr in grads]).sum(0).sqrt()
        scale = (1.0 / (norms + 1e-6)).clamp(max=1.0)
        for gr in grads:
            gr.mul_(scale.view(-1, *[1] * (gr.dim() - 1)))
        opt.step()

    return step


def _in_child(target, *args):
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=target, args=(*args, queue))
    proc.start()
    out = queue.get()
    proc.join()
    return out


def per_policy(config, specs: list[str], threads: int) -> None:
    """Train one policy end to end per recipe (each in a fresh process, on the default build's stores) and print
    its CPU-seconds beside the first recipe's and beside the floor for that recipe's optimizer steps."""
    from ocpipe import paths
    from ocpipe.policy.settings import PolicySettings

    width = max(58, *(len(spec) + 2 for spec in specs))
    print(f"{'recipe':<{width}}{'epochs':>7}{'steps':>8}{'CPU s':>9}{'x first':>9}{'floor s':>9}{'x floor':>9}"
          f"  ({threads} thread{'s' * (threads > 1)})")
    first = None
    for spec in specs:
        p = resolve_with_overrides(config, spec)
        store = experiments.features_store(p)
        stores = {"features": REPO / paths.features_store(store),
                  "frames": REPO / paths.frames_store(experiments.frames_store(p))}
        if p["readout_scenes"]:
            stores["scenes"] = REPO / paths.named(paths.SCENES_STORE, store)
        missing = [str(f) for f in stores.values() if not f.exists()]
        if missing:
            sys.exit(f"{', '.join(missing)} missing: build the default stores first (make main)")
        d = data.load(p, stores["features"], stores["frames"], config["camera_approx"])
        loader = d.windows(PolicySettings.of(p), d.train_frames, p["batch_size"], 0,
                           every_step=p["action_loss"] == "every_step")
        got = _in_child(_train_worker, p, stores, threads, config["camera_approx"])
        steps = sum(loader.batches(epoch) for epoch in range(got["epochs"]))
        floor = _in_child(_floor_worker, p, steps, threads, d.meta["K"], d.meta["D"], "eager")
        first = first or got["cpu"]
        print(f"{spec:<{width}}{got['epochs']:>7}{steps:>8}{got['cpu']:>9.0f}"
              f"{got['cpu'] / first:>9.2f}{floor:>9.0f}{got['cpu'] / floor:>9.2f}")
    print()


def step_kernels(policy, threads: int, steps: int, K: int = 7, D: int = 64) -> None:
    """The floor's training step under each of KERNELS, each in a fresh process, against the eager step."""
    print(f"training step on random tensors, batch {policy['batch_size']}, width {policy['width']}, "
          f"{policy['layers']} layers, {threads} thread{'s' * (threads > 1)}, {steps} steps timed:")
    eager = None
    for kernel, label in KERNELS.items():
        ms = _in_child(_floor_worker, policy, steps, threads, K, D, kernel) / steps * 1000
        eager = eager or ms
        print(f"  {label:<28}{ms:>8.1f} ms CPU per policy step{ms / eager:>8.2f}x eager")
    print()


def resolve_with_overrides(config, spec: str) -> dict:
    """'goal2d' or 'goal2d:dropout=0.0,window=20' -> that experiment's policy with the overrides (YAML values)."""
    import yaml

    name, _, overrides = spec.partition(":")
    p = experiments.resolve(config, name)
    for item in filter(None, overrides.split(",")):
        key, _, value = item.partition("=")
        if key not in p:
            sys.exit(f"{spec}: {key!r} is not a policy key")
        p[key] = yaml.safe_load(value)
    return p


def time_experiments(config, names, features, frames, args):
    print(f"{'experiment':<34}{'params':>10}{'T':>8}{'s/epoch':>10}{'x goal2d':>10}  ({args.threads} threads)")
    base = None
    for name in names:
        p = resolve_with_overrides(config, name)
        if experiments.features_store(p) != experiments.features_store(experiments.resolve(config, "goal2d")):
            print(f"{name:<34}  skipped: needs {experiments.features_store(p)}")
            continue
        sec, n, total, params = seconds_per_epoch(p, features, frames, args.epoch_batches, args.threads,
                                                   config["camera_approx"])
        base = base or sec
        print(f"{name:<34}{params:>10}{p['window']:>8}{sec:>10.1f}{sec / base:>10.2f}  ({n} of {total} batches)")
    print()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(REPO / "config" / "config.yaml"))
    ap.add_argument("--synthetic", type=int, default=0, help="frames of a synthetic (N, 2, 7, 256) store instead")
    ap.add_argument("--random-batches", type=int, default=20, help="batches timed for the random-access loader")
    ap.add_argument("--epoch-batches", type=int, default=60, help="batches timed per model (epoch time extrapolated)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--experiments",
        nargs="*",
        default=[],
        help="also time an epoch of these config experiments (e.g. window20 window40, or goal2d:dropout=0.0 for "
        "one with overrides), side by side with goal2d; experiments on other tasks or encoders need their own "
        "features store",
    )
    ap.add_argument("--skip-loaders", action="store_true", help="only time epochs")
    ap.add_argument("--decoder", action="store_true", help="only time a training step with the whole decoder "
                    "against the last token only, for goal2d and --experiments (random batches, no store needed)")
    ap.add_argument("--decoder-steps", type=int, default=40)
    ap.add_argument("--per-policy", nargs="+", metavar="RECIPE", help="only train one policy end to end per recipe "
                    "(an experiment, with overrides as in --experiments; the first is the reference) and print CPU "
                    "seconds, the ratio to the first and to the floor (the train rule's threads: --threads 1)")
    ap.add_argument("--step-kernels", action="store_true", help="only time goal2d's training step on random "
                    "tensors in eager mode, under torch.compile, under bfloat16 autocast and stacked with four more "
                    "policies under torch.func.vmap (per policy; no store needed)")
    args = ap.parse_args()
    config = cfgmod.load(args.config)
    if args.step_kernels:
        step_kernels(experiments.resolve(config, "goal2d"), args.threads, 200)
        return
    if args.per_policy:
        per_policy(config, args.per_policy, args.threads)
        return
    policy = experiments.resolve(config, "goal2d")
    if args.decoder:
        for name in ["goal2d", *args.experiments]:
            time_decoder(resolve_with_overrides(config, name), args.decoder_steps, args.threads)
        return
    tmp = None
    if args.synthetic:
        from policy_stores import write_stores

        tmp = tempfile.TemporaryDirectory()
        n_eps = args.synthetic // 78
        features, frames = write_stores(Path(tmp.name), lengths=[78] * n_eps, K=7, D=256, chunk=4096)
        where = f"synthetic store: {n_eps * 78} frames x 2 cameras x 7 slots x 256 (float16), chunks of 4096"
    else:
        features = REPO / "results" / "features" / f"{experiments.features_store(policy)}.zarr"
        frames = REPO / "results" / "frames" / f"{experiments.frames_store(policy)}.zarr"
        if not features.exists():
            sys.exit(f"{features} is missing: build it first (make main) or pass --synthetic N")
        where = str(features)
    print(f"store: {where}\n")
    if args.experiments:
        time_experiments(config, ["goal2d", *args.experiments], features, frames, args)
    if args.skip_loaders:
        return
    chunk = measure_loader("chunk-aware", policy, features, frames, 0, config["camera_approx"])
    rand = measure_loader("random-access", policy, features, frames, args.random_batches,
                          config["camera_approx"])
    rate = lambda r: r["samples"] / r["seconds"]  # noqa: E731
    print(f"{'loader':<16}{'samples':>10}{'seconds':>10}{'samples/s':>12}{'peak RSS MB':>14}")
    for name, r in (("chunk-aware", chunk), ("random-access", rand)):
        print(f"{name:<16}{r['samples']:>10}{r['seconds']:>10.2f}{rate(r):>12.1f}{r['peak_rss_mb']:>14.0f}")
    print(f"ratio chunk-aware / random-access: {rate(chunk) / rate(rand):.1f}x samples/s\n")

    thesis = {**policy, "width": 256, "layers": 8, "heads": 8}
    print(f"{'model':<28}{'params':>10}{'s/epoch':>10}  (batch {policy['batch_size']}, {args.threads} threads)")
    results = {}
    label = lambda p: f"w{p['width']}, {p['layers']} layers"  # noqa: E731
    for name, p in ((f"default ({label(policy)})", policy), (f"thesis ({label(thesis)})", thesis)):
        sec, n, total, params = seconds_per_epoch(p, features, frames, args.epoch_batches, args.threads,
                                                   config["camera_approx"])
        results[name] = sec
        print(f"{name:<28}{params:>10}{sec:>10.1f}  ({n} of {total} batches timed)")
    a, b = results.values()
    print(f"ratio thesis / default: {b / a:.1f}x seconds per epoch")


if __name__ == "__main__":
    main()
