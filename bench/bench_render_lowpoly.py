"""Milliseconds per camera render step with the robot's visual meshes decimated (sim.robot_visual_keep) and the
ground redrawn coarse (sim.ground_cells), against today's full meshes.

    .venv/bin/python bench/bench_render_lowpoly.py
    .venv/bin/python bench/bench_render_lowpoly.py --variants today 0.1:2 0.2:2 0.2:none --steps 50

Each variant is KEEP:CELLS ('today' = neither; 'none' leaves that one as today). All variants live in one process
(one env each, same task, seed and actions) and are timed in turn, step by step, so load on the machine hits them
alike. A render step is what the frames stage does per frame: update the scene and capture the cameras
(BaseEnv._get_obs_sensor_data); the physics step between renders is not timed. Wall and CPU (user + system of the
process) milliseconds are reported; with lavapipe_threads 0 the rasterizer runs in this thread, so the two agree on
an idle machine. The shader pack and lavapipe threads are the config's."""

from __future__ import annotations

import argparse
import copy
import statistics
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _cpu() -> float:
    return time.process_time()  # user + system of the process, all threads; finer than os.times' clock ticks


def parse_variant(text: str) -> tuple[str, float | None, int | None]:
    if text == "today":
        return text, None, None
    keep, _, cells = text.partition(":")
    keep_v = None if keep in ("", "none") else float(keep)
    cells_v = None if cells in ("", "none") else int(cells)
    return text, keep_v, cells_v


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=str(REPO / "config" / "config.yaml"))
    ap.add_argument("--task", default="PickCube-v1")
    ap.add_argument("--camera-set", default="dual")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--obs-mode", default="rgb", help="rgb (evaluation) or rgb+segmentation (frames stage)")
    ap.add_argument("--variants", nargs="+", default=["today", "0.1:2", "0.2:2"],
                    help="KEEP:CELLS per variant, or 'today'; the first is the baseline of the ratios")
    ap.add_argument("--steps", type=int, default=30, help="timed render steps per variant")
    ap.add_argument("--warmup", type=int, default=3, help="untimed render steps first (shader compilation)")
    ap.add_argument("--seed", type=int, default=10_000)
    args = ap.parse_args(argv)

    import numpy as np
    import torch

    from ocpipe.config import validate as cfgmod
    from ocpipe.sim import envs as sim

    torch.set_num_threads(1)
    base_cfg = cfgmod.load(args.config)
    variants = [parse_variant(v) for v in args.variants]
    envs = []
    for _name, keep, cells in variants:
        cfg = copy.deepcopy(base_cfg)
        cfg["sim"]["robot_visual_keep"], cfg["sim"]["ground_cells"] = keep, cells
        env = sim.make_env(args.task, cfg, args.camera_set, args.resolution, obs_mode=args.obs_mode)
        env.reset(seed=args.seed)
        envs.append(env)

    # the same slow sweep of joint targets around the start pose in every env, so the robot moves in view
    u0 = envs[0].unwrapped
    start = u0.agent.robot.get_qpos()[:, :8].clone()
    start[:, 7] = 1.0

    def action(t: int) -> torch.Tensor:
        a = start.clone()
        a[:, :7] += 0.3 * np.sin(0.1 * t + np.arange(7))
        return a

    wall = [[] for _ in envs]
    cpu = [[] for _ in envs]
    for t in range(args.warmup + args.steps):
        for i, env in enumerate(envs):
            u = env.unwrapped
            u._step_action(action(t))
            w0, c0 = time.perf_counter(), _cpu()
            u._get_obs_sensor_data()
            if t >= args.warmup:
                wall[i].append(1000 * (time.perf_counter() - w0))
                cpu[i].append(1000 * (_cpu() - c0))
    for env in envs:
        env.close()

    res = args.resolution
    print(f"{args.task} {args.camera_set} {res} px, shader {base_cfg['sim']['shader']}, "
          f"lavapipe_threads {base_cfg['sim'].get('lavapipe_threads')}, obs {args.obs_mode}, "
          f"{args.steps} steps per variant after {args.warmup} warm-up, alternating")
    print(f"{'variant':<12} {'keep':>5} {'cells':>5} {'wall ms':>9} {'median':>8} {'cpu ms':>8} {'x today':>8}")
    base_wall = statistics.fmean(wall[0])
    for (name, keep, cells), w, c in zip(variants, wall, cpu):
        print(f"{name:<12} {keep if keep is not None else '-':>5} {cells if cells is not None else '-':>5} "
              f"{statistics.fmean(w):9.2f} {statistics.median(w):8.2f} {statistics.fmean(c):8.2f} "
              f"{statistics.fmean(w) / base_wall:8.3f}")


if __name__ == "__main__":
    main()
