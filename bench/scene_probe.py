"""Is the cube's position in the frozen tokens, or only in the scenes the demos happen to show?

    .venv/bin/python bench/scene_probe.py --scenes 4000 --test-scenes 600

A features store of 100 demos shows the cube at 100 places only, and on most frames the gripper is next to it, so
a probe fitted on demo frames can place the cube by the arm. This renders extra scenes of the task (resets of
seeds outside the demo and evaluation pools, the arm set to a random demo frame's pre-grasp pose, the cube
wherever the reset put it: the workflow's `scenes` rule, ocpipe.features.scenes), encodes them with the build's
frozen encoder, and fits the MLP probe of the features diagnostics on demo frames alone and on demo frames plus
the scenes. It prints, for each, the cube error (median
and p90, cm) on the held-out demos' frames, on their first frames only (the arm at home: the cube by itself) and
on held-out scenes. Reads `results/` (frames store, features store, slots_ssl encoder) of a built default
profile; rendering and encoding take ~60 ms per scene on one core."""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch
import zarr

from ocpipe.config import validate as cfgmod
from ocpipe.encoders import registry
from ocpipe.features import probes, scenes
from ocpipe.features.encode import open_features
from ocpipe.frames.store import open_store

REPO = Path(__file__).resolve().parents[1]
STORE = "PickCube-v1_dual_128"


def scenes_of(config: dict, results: Path, n: int, seed_start: int, out: Path) -> dict:
    """``n`` scenes from reset seed ``seed_start`` as the workflow's `scenes` rule makes them: tokens, positions."""
    frames = results / "frames" / f"{STORE}.zarr"
    encoder = registry.build("slots_ssl", config["encoders"], frames, results / "encoders" / "slots_ssl" / "model.pt")
    scenes.render_scenes(encoder, config, "PickCube-v1", "dual", 128, frames, out, n, seed_start, config["seed"],
                         dtype=config["features"]["dtype"], near_fraction=config["scenes"]["near_fraction"],
                         near_radius=config["scenes"]["near_radius"])
    root = zarr.open_group(str(out), mode="r")
    return {"tokens": root["tokens"][...].astype(np.float32), "obj_pos": root["obj_pos"][...]}


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
    frames = open_store(results / "frames" / f"{STORE}.zarr", need=("obj_pos",))
    tokens = open_features(results / "features" / f"{STORE}_slots_ssl.zarr")["tokens"][...].astype(np.float32)
    ep, obj = frames["episode_index"][...], frames["obj_pos"][...]
    test = ep >= ep.max() + 1 - args.holdout_episodes
    first = np.r_[True, ep[1:] != ep[:-1]]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        train_sc = scenes_of(config, results, args.scenes, args.seed_start, Path(tmp) / "train.zarr")
        test_sc = scenes_of(config, results, args.test_scenes, args.seed_start + args.scenes, Path(tmp) / "test.zarr")
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
