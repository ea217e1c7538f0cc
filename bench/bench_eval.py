"""Where a closed-loop evaluation step goes, and closed-loop episodes per core-minute under three settings.

    .venv/bin/python bench/bench_eval.py                      # on the default build (needs a trained checkpoint)
    .venv/bin/python bench/bench_eval.py --checkpoint results/runs/goal3d/checkpoints/epoch_0016.pt --steps 80

For each setting (shader pack, lavapipe threads, decimated robot and floor visuals) it times, each in a fresh
process (lavapipe reads its thread count once, when the Vulkan driver loads): (a) the bare physics step (no
camera), (b) the step with the study's two cameras rendered, (c) a full closed-loop step (render, encode,
policy) of a real checkpoint. It reports wall and CPU milliseconds per step (CPU = user + system time of the
process and all its threads: what a step costs a machine running one evaluation job per core) and closed-loop
episodes per core-minute for a 100-step episode, and the ratio of each setting to today's ('new' is
config/config.yaml's default). Run it on an otherwise idle machine: wall times move with load, CPU times much
less."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# today: the settings before the evaluation-throughput work; new: the default profile's
SETTINGS = {
    "today": {"shader": "default", "lp_threads": None, "robot_visual_keep": None, "ground_cells": None},
    "shader+lp": {"shader": "minimal", "lp_threads": "0", "robot_visual_keep": None, "ground_cells": None},
    "new": {"shader": "minimal", "lp_threads": "0", "robot_visual_keep": 0.1, "ground_cells": 2},
}


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def _timed(step, n: int) -> dict:
    step()  # warm-up: first render compiles shaders
    w0, c0 = time.perf_counter(), _cpu()
    for _ in range(n):
        step()
    return {"wall_ms": 1000 * (time.perf_counter() - w0) / n, "cpu_ms": 1000 * (_cpu() - c0) / n}


def worker(mode: str, setting: dict, checkpoint: str, steps: int) -> dict:
    import torch

    from ocpipe.config import validate as cfgmod
    from ocpipe.evaluation.closed_loop import ClosedLoop
    from ocpipe.sim import envs as sim

    torch.set_num_threads(1)
    config = cfgmod.load(REPO / "config" / "config.yaml")
    config["sim"].update({k: setting[k] for k in ("shader", "robot_visual_keep", "ground_cells")})
    # the parent set LP_NUM_THREADS (or left it unset) before the driver loads; the config must not override it
    config["sim"]["lavapipe_threads"] = None
    if mode == "closed_loop":
        frames = REPO / "results" / "frames" / "PickCube-v1_dual_128.zarr"
        loop = ClosedLoop(checkpoint, config, frames, REPO / "results" / "encoders" / "slots_ssl" / "model.pt")
        obs, _ = loop.env.reset(seed=10000)
        hold = torch.as_tensor(sim.task_readouts(loop.env)["qpos"][None, :8].copy())
        hold[:, 7] = 1.0

        def step():
            tokens, proprio, goal, labels = loop._observe(obs, first=False)
            seq = [
                torch.as_tensor(x)[None, None].repeat(1, loop.policy.network.window, *([1] * torch.as_tensor(x).dim()))
                for x in (tokens, proprio, goal)
            ]
            loop.model(*seq, torch.as_tensor(tokens)[None])
            loop.env.step(hold)

        return _timed(step, steps)
    env = sim.make_env("PickCube-v1", config, None if mode == "physics" else "dual", 128, obs_mode="rgb")
    env.reset(seed=10000)
    hold = torch.as_tensor(env.unwrapped.agent.robot.get_qpos()[:, :8].clone())
    hold[:, 7] = 1.0
    return _timed(lambda: env.step(hold), steps)


def measure(setting: dict, mode: str, checkpoint: str, steps: int) -> dict:
    env = dict(os.environ)
    env.pop("LP_NUM_THREADS", None)
    if setting["lp_threads"] is not None:
        env["LP_NUM_THREADS"] = setting["lp_threads"]
    out = subprocess.run(
        [
            sys.executable,
            __file__,
            "--worker",
            mode,
            "--setting",
            json.dumps(setting),
            "--checkpoint",
            checkpoint,
            "--steps",
            str(steps),
        ],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def default_checkpoint() -> str:
    found = sorted((REPO / "results").glob("runs/*/checkpoints/epoch_*.pt"))
    if not found:
        sys.exit(
            "bench_eval: no policy checkpoint under results/runs/: build one first "
            "(snakemake --cores 2 results/runs/goal3d/checkpoints) or pass --checkpoint"
        )
    return str(found[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint")
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--episode-steps", type=int, default=100, help="steps of the episode behind 'episodes/core-min'")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--setting", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, json.loads(args.setting), args.checkpoint, args.steps)))
        return
    ckpt = args.checkpoint or default_checkpoint()
    results = {
        name: {mode: measure(s, mode, ckpt, args.steps) for mode in ("physics", "render", "closed_loop")}
        for name, s in SETTINGS.items()
    }
    print(
        f"checkpoint {ckpt}; {args.steps} timed steps per cell; settings: "
        + "; ".join(
            f"{n}: shader {s['shader']}, LP_NUM_THREADS {s['lp_threads'] or 'unset'}, robot visuals "
            f"{s['robot_visual_keep'] or 'original'}, floor cells {s['ground_cells'] or 'original'}"
            for n, s in SETTINGS.items()
        )
    )
    others = [n for n in SETTINGS if n != "today"]
    print(
        f"{'step':<40}"
        + "".join(f"{n + ' wall/cpu ms':>24}" for n in SETTINGS)
        + "".join(f"{'today/' + n:>16}" for n in others)
    )
    labels = {
        "physics": "(a) physics only",
        "render": "(b) physics + 2 cameras rendered",
        "closed_loop": "(c) closed loop (render+encode+policy)",
    }
    for mode, label in labels.items():
        cells = {n: results[n][mode] for n in SETTINGS}
        print(
            f"{label:<40}"
            + "".join(f"{c['wall_ms']:>14.1f} / {c['cpu_ms']:>6.1f}" for c in cells.values())
            + "".join(f"{cells['today']['cpu_ms'] / cells[n]['cpu_ms']:>15.2f}x" for n in others)
        )
    per_min = {n: 60000 / (results[n]["closed_loop"]["cpu_ms"] * args.episode_steps) for n in SETTINGS}
    print(
        f"closed-loop episodes per core-minute ({args.episode_steps} steps): "
        + ", ".join(f"{n} {v:.2f}" for n, v in per_min.items())
        + "; ratio "
        + ", ".join(f"{n}/today {per_min[n] / per_min['today']:.2f}x" for n in others)
    )
    for n in SETTINGS:
        r = results[n]
        render = r["render"]["cpu_ms"] - r["physics"]["cpu_ms"]
        rest = r["closed_loop"]["cpu_ms"] - r["render"]["cpu_ms"]
        print(
            f"  {n}: of {r['closed_loop']['cpu_ms']:.1f} CPU ms per step, physics {r['physics']['cpu_ms']:.1f}, "
            f"rendering {render:.1f}, encoding + policy + readouts {rest:.1f}"
        )


if __name__ == "__main__":
    main()
