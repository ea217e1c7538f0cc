"""The lever ladder: train one policy per setting on the built stores, then measure it without and with the
simulator, so each change to the recipe is judged by the same three numbers side by side.

    .venv/bin/python bench/levers.py goal3d goal3d:joint_targets=residual state_control --episodes 20

Each argument is an experiment of config `experiments`, optionally with `:key=value,key=value` overrides of its
policy settings (values parsed as YAML). For each it prints the training time, the open-loop action error on
the held-out demos (policy.val_episodes) and the closed-loop success rate on `--episodes` seeds of the validation
pool (evaluation.validation_pool_size: never the seeds the tables report; every lever sees the same episodes),
and appends a row to
results/levers/levers.csv. Runs one lever after another on `--threads` threads; start two processes to use two
cores."""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np
import polars as pl
import torch
import yaml

from ocpipe.config import experiments
from ocpipe.config import validate as cfgmod
from ocpipe.evaluation import closed_loop, jobs
from ocpipe.policy.training import train

REPO = Path(__file__).resolve().parents[1]


def parse_lever(arg: str, config: dict) -> tuple[dict, dict]:
    """'exp:key=v,evaluation.key=v' -> (policy settings, evaluation settings)."""
    name, _, rest = arg.partition(":")
    overrides = {k: yaml.safe_load(v) for k, v in (kv.split("=", 1) for kv in rest.split(",") if kv)}
    evaluation_cfg = dict(config["evaluation"])
    for k in [k for k in overrides if k.startswith("evaluation.")]:
        key = k.removeprefix("evaluation.")
        value = overrides.pop(k)
        evaluation_cfg[key] = {**evaluation_cfg[key], "PickCube-v1": value} if key == "episode_cap" else value
    return {**experiments.resolve(config, name), **overrides}, evaluation_cfg


def run_lever(label: str, policy: dict, config: dict, episodes: int, threads: int, out_root: Path,
              results: Path) -> dict:
    store = experiments.features_store(policy)
    enc_ckpt = results / "encoders" / "slots_ssl" / "model.pt" if policy["encoder"] == "slots_ssl" else None
    # one training per distinct policy: levers that differ only in evaluation settings share it
    key = hashlib.sha256(json.dumps({**policy, "name": None}, sort_keys=True).encode()).hexdigest()[:12]
    out_dir = out_root / f"{policy['name']}-{key}"
    t0 = time.perf_counter()
    if (out_dir / "train_log.parquet").is_file():
        log = pl.read_parquet(out_dir / "train_log.parquet")
    else:
        scenes = results / "features" / f"{store}.scenes.zarr" if policy.get("readout_scenes") else None
        log = train(policy, config["seed"], results / "features" / f"{store}.zarr",
                    results / "frames" / f"{experiments.frames_store(policy)}.zarr", out_dir, threads=threads,
                    scenes_path=scenes, camera_approx=config["camera_approx"])
    train_s = float(log["seconds"].sum())
    torch.set_num_threads(threads)
    ckpt = out_dir / "checkpoints" / f"epoch_{policy['epochs']:04d}.pt"
    loop = closed_loop.ClosedLoop(ckpt, config, results / "frames" / f"{experiments.frames_store(policy)}.zarr",
                                  enc_ckpt)
    seeds = jobs.validation_seeds(config["evaluation"], episodes, config["seed"])
    t0 = time.perf_counter()
    try:
        eps, steps = closed_loop.run(loop, seeds, {"exp": label, "checkpoint": policy["epochs"], "run": 0})
    finally:
        loop.close()
    # the per-step log, for looking into a lever afterwards (one file per evaluation setting)
    ev_key = hashlib.sha256(json.dumps(config["evaluation"], sort_keys=True).encode()).hexdigest()[:8]
    steps.write_parquet(out_dir / f"steps_{episodes}_{ev_key}.parquet")
    last = log.row(-1, named=True)
    row = {
        "lever": label,
        "dir": out_dir.name,
        "epochs": policy["epochs"],
        "train_s": round(train_s, 1),
        "val_joint_err_rad": last.get("val_joint_err_rad"),
        "val_first_joint_err_rad": last.get("val_first_joint_err_rad"),
        "val_gripper_agree": last.get("val_gripper_agree"),
        "episodes": len(eps),
        "successes": int(eps.filter(~pl.col("trivial"))["success"].sum()),
        "sr": closed_loop.success_rate(eps),
        "mean_steps": float(eps["steps"].mean()),
        "eval_s": round(time.perf_counter() - t0, 1),
        **readout_errors(steps),
    }
    print(json.dumps(row), flush=True)
    return row


def readout_errors(steps: pl.DataFrame) -> dict:
    """Median distance (cm) between the policy's object read-out and the true object, over the closed-loop steps
    before a grasp (after it the object rides in a hand that hides it) and at each episode's first step, and the
    same for the estimate the policy saw (``obj_seen``: the read-out after evaluation.readout_filter); empty for
    policies without a read-out."""
    est = np.asarray(steps["obj_est"].to_list(), dtype=np.float64)
    if np.isnan(est).all():
        return {}
    obj = np.asarray(steps["obj_pos"].to_list())
    err = 100 * np.linalg.norm(est - obj, axis=1)
    free = ~np.asarray(steps["is_grasped"].to_list(), dtype=bool)
    first = (steps["step"] == 0).to_numpy()
    row = {"readout_cl_cm": round(float(np.median(err[free])), 2),
           "readout_cl_p90_cm": round(float(np.percentile(err[free], 90)), 2),
           "readout_cl_first_cm": round(float(np.median(err[first])), 2)}
    if "obj_seen" in steps.columns:
        seen = 100 * np.linalg.norm(np.asarray(steps["obj_seen"].to_list(), dtype=np.float64) - obj, axis=1)
        row |= {"seen_cl_cm": round(float(np.median(seen[free])), 2),
                "seen_cl_p90_cm": round(float(np.percentile(seen[free], 90)), 2)}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("levers", nargs="+")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--configfile", nargs="*", default=[str(REPO / "config" / "config.yaml")])
    ap.add_argument("--results", default=str(REPO / "results"), help="the build whose stores the levers read")
    ap.add_argument("--out", help="where trained levers and levers.csv go (default: RESULTS/levers)")
    args = ap.parse_args()
    config = cfgmod.load(*args.configfile)
    out_root = Path(args.out or Path(args.results) / "levers")
    out_root.mkdir(parents=True, exist_ok=True)
    for arg in args.levers:
        policy, evaluation_cfg = parse_lever(arg, config)
        row = run_lever(
            arg,
            policy,
            {**config, "evaluation": evaluation_cfg},
            args.episodes,
            args.threads,
            out_root,
            Path(args.results),
        )
        csv = out_root / "levers.csv"
        table = pl.DataFrame([row])
        if csv.is_file():
            table = pl.concat([pl.read_csv(csv), table], how="diagonal_relaxed")
        table.write_csv(csv)


if __name__ == "__main__":
    main()
