"""Where do a policy's grasps miss? Runs one checkpoint in closed loop on the held-out seeds of stability run 0 and
prints, per episode, the closest the gripper's TCP came to the cube (and the offset TCP - cube there, cm), what the
policy's auxiliary head believed the cube's position to be (when it has one), and the success rate by the cube's
yaw (mod 90 degrees: the grasp must turn the hand to the cube's faces).

    .venv/bin/python bench/grasp_misses.py results/runs/goal3d/checkpoints/epoch_0016.pt --episodes 20

A closest approach of ~3 cm with +3 cm in z means the fingers came down on the cube's top face (the cube is 4 cm);
a lateral offset of 2-3 cm at grasp height means the hand closed beside it. The demos close the gripper with the
TCP within 3 mm of the cube's centre (`--demos` prints that for the build's frames store)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from ocpipe.config import experiments
from ocpipe.config import validate as cfgmod
from ocpipe.encoders.state import yaw
from ocpipe.evaluation import closed_loop, jobs
from ocpipe.frames.store import open_store
from ocpipe.sim import envs as sim

REPO = Path(__file__).resolve().parents[1]


def yaw_mod90(quat_wxyz: np.ndarray) -> float:
    """The cube's yaw in degrees, folded to [-45, 45): its faces repeat every quarter turn."""
    return float((np.degrees(yaw(quat_wxyz)) + 45) % 90 - 45)


def demo_grasps(frames_path: Path) -> None:
    frames = open_store(frames_path, need=("tcp_pos", "obj_pos", "action"))
    off = frames.attrs["episode_offsets"]
    tcp, obj, grip = frames["tcp_pos"][:], frames["obj_pos"][:], frames["action"][:, 7]
    gaps = []
    for s, e in zip(off[:-1], off[1:]):
        close = s + int(np.argmax(grip[s:e] < 0))  # the first closing command
        gaps.append(np.linalg.norm(tcp[close] - obj[close]))
    print(f"demos: TCP - cube at the first closing command: median {np.median(gaps) * 100:.2f} cm, "
          f"max {np.max(gaps) * 100:.2f} cm over {len(gaps)} episodes")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--results", default=str(REPO / "results"))
    ap.add_argument("--configfile", nargs="*", default=[str(REPO / "config" / "config.yaml")])
    ap.add_argument("--demos", action="store_true", help="also print the demos' TCP - cube distance at grasp")
    args = ap.parse_args()
    torch.set_num_threads(1)
    config = cfgmod.load(*args.configfile)
    results = Path(args.results)
    policy = torch.load(args.checkpoint, map_location="cpu", weights_only=False)["policy"]
    frames_path = results / "frames" / f"{experiments.frames_store(policy)}.zarr"
    if args.demos:
        demo_grasps(frames_path)
    enc = results / "encoders" / "slots_ssl" / "model.pt" if policy["encoder"] == "slots_ssl" else None
    loop = closed_loop.ClosedLoop(args.checkpoint, config, frames_path, enc)
    beliefs: list[np.ndarray] = []
    forward = loop.model.forward

    def forward_recording_aux(*a, **k):  # keep what the auxiliary head (or the read-out) believes at every query
        out = forward(*a, **k)
        norm = loop.model.normalizer
        if out.object_pos is not None:
            beliefs.append(norm.aux.invert(out.object_pos)[0].numpy())
        elif out.readout is not None:
            beliefs.append(norm.pose.invert(out.readout[0, -1])[:3].numpy())
        return out

    loop.model.forward = forward_recording_aux
    seeds = jobs.validation_seeds(config["evaluation"], args.episodes, config["seed"])
    rows = []
    try:
        for seed in seeds:
            beliefs.clear()
            row, steps = loop.episode(seed)
            with torch.inference_mode():
                loop.env.reset(seed=seed)
                yaw = yaw_mod90(sim.task_readouts(loop.env)["obj_quat"])
            tcp, obj = np.array(steps["tcp_pos"]), np.array(steps["obj_pos"])
            d = np.linalg.norm(tcp - obj, axis=1)
            t = int(d.argmin())
            line = (f"seed {seed} {'success' if row['success'] else 'failure'} in {row['steps']} steps; closest "
                    f"{d[t] * 100:.1f} cm at step {t}, offset {np.round((tcp[t] - obj[t]) * 100, 1)} cm; "
                    f"grasped {any(steps['is_grasped'])}; cube yaw {yaw:+.0f} deg")
            if beliefs:
                q = np.arange(0, len(obj), loop.execute)[: len(beliefs)]
                err = np.linalg.norm(np.array(beliefs) - obj[q], axis=1) * 100
                line += f"; aux belief error first {err[0]:.1f} cm, median {np.median(err):.1f} cm"
            print(line, flush=True)
            rows.append((row["success"] and not row["trivial"], abs(yaw), d[t]))
    finally:
        loop.close()
    r = np.array(rows, dtype=float)
    print(f"SR {r[:, 0].mean():.2f} over {len(r)} episodes; closest approach in failures: median "
          f"{np.median(r[r[:, 0] == 0, 2]) * 100 if (r[:, 0] == 0).any() else float('nan'):.1f} cm")
    for lo, hi in ((0, 15), (15, 30), (30, 46)):
        m = (r[:, 1] >= lo) & (r[:, 1] < hi)
        if m.any():
            print(f"  |cube yaw mod 90| {lo}-{hi} deg: {int(r[m, 0].sum())}/{int(m.sum())}")


if __name__ == "__main__":
    main()
