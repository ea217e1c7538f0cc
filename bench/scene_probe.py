"""Is the cube's position in the frozen tokens, or only in the scenes the demos happen to show?

    .venv/bin/python bench/scene_probe.py --scenes 4000 --test-scenes 600

A features store of 100 demos shows the cube at 100 places only, and on most frames the gripper is next to it, so
a probe fitted on demo frames can place the cube by the arm. This renders extra scenes of the task (resets of
seeds outside the demo and evaluation pools, the arm set to a random pre-grasp pose of a training demo, the cube
wherever the reset put it), encodes them with the build's frozen encoder, and fits the MLP probe of the features
diagnostics on demo frames alone and on demo frames plus the scenes. It prints, for each, the cube error (median
and p90, cm) on the held-out demos' frames, on their first frames only (the arm at home: the cube by itself) and
on held-out scenes. Reads `results/` (frames store, features store, slots_ssl encoder) of a built default
profile; rendering and encoding take ~60 ms per scene on one core."""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ocpipe.config import validate as cfgmod
from ocpipe.encoders import registry
from ocpipe.features import probes
from ocpipe.features.encode import open_features
from ocpipe.frames.store import open_store
from ocpipe.sim import envs

REPO = Path(__file__).resolve().parents[1]
STORE = "PickCube-v1_dual_128"


def render_scenes(config: dict, results: Path, n: int, seed_start: int, arm_poses: np.ndarray) -> dict:
    """``n`` scenes: reset(seed_start + i), the arm set to a random row of ``arm_poses``; tokens and labels."""
    frames = results / "frames" / f"{STORE}.zarr"
    encoder = registry.build("slots_ssl", config["encoders"], frames, results / "encoders" / "slots_ssl" / "model.pt")
    env = envs.make_env("PickCube-v1", config, "dual", 128)
    uids = [envs.SIM_CAMERA_UID[c] for c in envs.CAMERA_SETS["dual"]]
    rng = np.random.default_rng(seed_start)
    tokens, obj = [], []
    try:
        for i in tqdm(range(n), desc=f"scenes from seed {seed_start}", unit="scene"):
            env.reset(seed=seed_start + i)
            qpos = arm_poses[rng.integers(len(arm_poses))]
            env.unwrapped.agent.robot.set_qpos(torch.as_tensor(qpos[None], dtype=torch.float32))
            obs = env.unwrapped.get_obs()  # renders the cameras with the arm where it was just put
            rgb = torch.stack([obs["sensor_data"][u]["rgb"][0] for u in uids])[None]
            with torch.inference_mode():
                tok, _ = encoder.encode(rgb)
            tokens.append(tok[0].half().float().numpy())  # rounded as the features store keeps them
            obj.append(envs.task_readouts(env)["obj_pos"])
    finally:
        env.close()
    return {"tokens": np.stack(tokens), "obj_pos": np.stack(obj)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=4000, help="extra training scenes")
    ap.add_argument("--test-scenes", type=int, default=600)
    ap.add_argument("--seed-start", type=int, default=50_000, help="first reset seed of the training scenes")
    ap.add_argument("--holdout-episodes", type=int, default=10, help="last demos held out of every probe")
    ap.add_argument("--epochs", type=int, default=60)
    ap.add_argument("--results", default=str(REPO / "results"))
    ap.add_argument("--configfile", nargs="*", default=[str(REPO / "config" / "config.yaml")])
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    torch.set_num_threads(1)
    config, results = cfgmod.load(*args.configfile), Path(args.results)
    pool = config["evaluation"]["seed_pool_start"], config["evaluation"]["seed_pool_size"]
    if args.seed_start < pool[0] + pool[1] and args.seed_start + args.scenes + args.test_scenes > pool[0]:
        raise SystemExit(f"--seed-start {args.seed_start}: the scenes would overlap the evaluation seeds "
                         f"{pool[0]}..{pool[0] + pool[1] - 1}")
    frames = open_store(results / "frames" / f"{STORE}.zarr", need=("qpos", "obj_pos", "is_grasped"))
    tokens = open_features(results / "features" / f"{STORE}_slots_ssl.zarr")["tokens"][...].astype(np.float32)
    ep, obj = frames["episode_index"][...], frames["obj_pos"][...]
    test = ep >= ep.max() + 1 - args.holdout_episodes
    first = np.r_[True, ep[1:] != ep[:-1]]
    arm_poses = frames["qpos"][...][~test & ~frames["is_grasped"][...]]
    t0 = time.perf_counter()
    train_sc = render_scenes(config, results, args.scenes, args.seed_start, arm_poses)
    test_sc = render_scenes(config, results, args.test_scenes, args.seed_start + args.scenes, arm_poses)
    print(f"rendered and encoded {args.scenes + args.test_scenes} scenes in {time.perf_counter() - t0:.0f} s")

    def flat(x):
        return x.reshape(len(x), -1)

    evals = {"held-out demo frames": (tokens[test], obj[test]),
             "their first frames": (tokens[test & first], obj[test & first]),
             "held-out scenes": (test_sc["tokens"], test_sc["obj_pos"])}
    fits = {"demo frames": (tokens[~test], obj[~test]),
            f"demo frames + {args.scenes} scenes": (np.concatenate([tokens[~test], train_sc["tokens"]]),
                                                    np.concatenate([obj[~test], train_sc["obj_pos"]]))}
    x_eval = np.concatenate([flat(x) for x, _ in evals.values()])
    cuts = np.cumsum([0] + [len(x) for x, _ in evals.values()])
    print(f"{'probe fitted on':<28}" + "".join(f"{name:>26}" for name in evals))
    for label, (x, y) in fits.items():
        pred = probes.mlp(flat(x), y, x_eval, seed=config["seed"], epochs=args.epochs)
        cells = []
        for i, (_, truth) in enumerate(evals.values()):
            e = probes.error_cm(pred[cuts[i]:cuts[i + 1]], truth)
            cells.append(f"{e['median_cm']:.2f} (p90 {e['p90_cm']:.2f}) cm")
        print(f"{label:<28}" + "".join(f"{c:>26}" for c in cells), flush=True)


if __name__ == "__main__":
    main()
