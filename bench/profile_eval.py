"""Where one closed-loop episode's CPU time goes: rendering, the encoder's CNN and Slot Attention, the policy, and
the rest (physics, observation building, logging), from a CPU-time profile (cProfile with process time, so a
loaded machine inflates wall time but not these shares).

    .venv/bin/python bench/profile_eval.py results/runs/goal2d/checkpoints/epoch_0016.pt
    .venv/bin/python bench/profile_eval.py CKPT --seed 9001 --top 30      # and the 30 costliest calls

Run from a build's root (its config/config.yaml, frames store and encoder are read as the workflow would). The
episode runs to success or the cap; one warm-up episode runs first (shader compilation, lazy imports)."""

from __future__ import annotations

import argparse
import cProfile
import inspect
import pstats
import time
from pathlib import Path

import torch
import yaml
from mani_skill.utils.structs.render_camera import RenderCamera

from ocpipe import paths
from ocpipe.config.validate import validate
from ocpipe.encoders.slot_attention import SlotAttention
from ocpipe.encoders.ssl_slots import SSLSlotEncoder
from ocpipe.evaluation.closed_loop import ClosedLoop
from ocpipe.policy.checkpoint import load_policy
from ocpipe.policy.model import SequencePolicy

# (label, profiled function): each one's cumulative CPU time; 'rest' is the episode's total less these
PARTS = (
    ("render (SAPIEN, lavapipe)", RenderCamera.get_picture),
    ("encoder CNN and colour/position inputs", SSLSlotEncoder.encode),
    ("encoder Slot Attention", SlotAttention.forward),
    ("policy forward", SequencePolicy.forward),
    ("object read-out per step", ClosedLoop.object_pose),
)


def cumulative(stats: pstats.Stats, function) -> float:
    """CPU seconds spent in ``function`` and what it calls (its cumulative time in the profile)."""
    code = inspect.unwrap(function).__code__  # the function itself, not a decorator's wrapper
    entry = stats.stats.get((code.co_filename, code.co_firstlineno, code.co_name))
    return entry[3] if entry else 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--seed", type=int, default=9001, help="reset seed of the profiled episode (9000: the warm-up)")
    ap.add_argument("--encoder-checkpoint", help="the frozen encoder's weights (default: the workflow's slots_ssl "
                    "model; none for the state control)")
    ap.add_argument("--top", type=int, default=0, help="also print this many calls by cumulative CPU time")
    args = ap.parse_args()
    torch.set_num_threads(1)  # as an evaluation job runs (compute.evaluate.threads: 1)
    config = yaml.safe_load(Path(args.config).read_text())
    validate(config)
    _, policy, meta = load_policy(args.checkpoint, "cpu")
    encoder = policy.stores.encoder
    weights = args.encoder_checkpoint or {"slots_ssl": f"{paths.SLOTS_SSL}/model.pt"}.get(encoder)
    loop = ClosedLoop(args.checkpoint, config, meta["frames_store"], weights)
    loop.episode(args.seed - 1)
    profile = cProfile.Profile(time.process_time)
    c0 = time.process_time()
    profile.enable()
    row, _ = loop.episode(args.seed)
    profile.disable()
    cpu = time.process_time() - c0
    loop.close()
    stats = pstats.Stats(profile)
    n = row["steps"]
    parts = {label: cumulative(stats, fn) for label, fn in PARTS}
    # encode() calls Slot Attention, and the read-out calls the policy's read-out head, not its forward
    parts["encoder CNN and colour/position inputs"] -= parts["encoder Slot Attention"]
    parts["rest (physics, observations, logging)"] = cpu - sum(parts.values())
    print(f"{args.checkpoint}: seed {args.seed}, {n} steps, success {row['success']}, "
          f"{1000 * cpu / n:.1f} CPU ms per step")
    for label, sec in parts.items():
        print(f"  {label:40s} {1000 * sec / n:6.1f} ms/step  {100 * sec / cpu:5.1f} %")
    if args.top:
        stats.sort_stats("cumulative").print_stats(args.top)


if __name__ == "__main__":
    main()
