"""Training one experiment: data from the features + frames stores, AdamW, checkpoints, resume after a kill.

Layout under ``out_dir`` (results/runs/{exp}):
  checkpoints/epoch_{E:04d}.pt  every save_every epochs and the last (model, resolved policy config,
                                normalization stats, optimizer state, epoch, training history)
  train_log.parquet             one row per epoch: epoch, loss, loss_joints, loss_gripper, lr, seconds
  .train/                       work folder while training runs: state.pt after every epoch and the checkpoints
                                so far. Snakemake deletes a failed job's declared outputs, so the resume state
                                must live outside them. A rerun resumes from state.pt when it was written under the
                                same settings; every epoch draws its randomness from (seed, epoch), so a resumed run
                                ends bit-identical to an uninterrupted one on the CPU."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from pathlib import Path

import numpy as np
import polars as pl
import torch
from tqdm import tqdm

from ..atomic import atomic_path
from ..devices import pick_device
from ..features import open_features
from ..frames_store import open_store
from . import normalization
from .model import SequencePolicy, loss_terms
from .weighting import loss_weights
from .windows import ChunkWindowLoader, Labels

log = logging.getLogger(__name__)


def goal_array(frames, policy: dict) -> np.ndarray:
    if policy["goal"] == "none":
        return np.zeros((frames["qpos"].shape[0], 0), dtype=np.float32)
    if policy["goal"] == "3d":
        return frames["goal_pos"][:].astype(np.float32)
    goal = frames[f"goal2d_{policy['goal_calibration']}"][:].astype(np.float32)
    if not np.isfinite(goal).all():
        raise ValueError(f"goal2d_{policy['goal_calibration']} has NaN in {frames.store}: the camera set "
                         f"{policy['cams']!r} has no {policy['goal_calibration']} 2d goal (policy.goal_calibration)")
    return goal


def load_data(policy: dict, features_path, frames_path):
    """-> (tokens zarr array, Labels, normalization stats computed from these frames, meta)."""
    feats, frames = open_features(features_path), open_store(frames_path)
    tokens = feats["tokens"]
    if tokens.shape[0] != frames["qpos"].shape[0]:
        raise ValueError(f"{features_path} has {tokens.shape[0]} frames but {frames_path} has {frames['qpos'].shape[0]}")
    if max(policy["cameras"]) >= tokens.shape[1]:
        raise ValueError(f"policy.cameras {policy['cameras']}: {features_path} has {tokens.shape[1]} cameras")
    qpos, action = frames["qpos"][:].astype(np.float32), frames["action"][:].astype(np.float32)
    stats = normalization.compute(qpos, action, policy["proprio"])
    labels = Labels.from_offsets(frames.attrs["episode_offsets"], normalization.proprio(qpos, stats),
                                 goal_array(frames, policy), normalization.action_to_model(action, stats))
    meta = {"K": int(tokens.shape[2]), "D": int(tokens.shape[3]), "features_store": str(features_path),
            "frames_store": str(frames_path), "encoder": feats.attrs.get("encoder"),
            "encoder_checkpoint_sha256": feats.attrs.get("checkpoint_sha256"),
            "cameras": [frames.attrs["cameras"][c] for c in policy["cameras"]], "tokens_dtype": str(tokens.dtype)}
    return tokens, labels, stats, meta


def _fingerprint(policy: dict, seed: int, meta: dict) -> str:
    blob = json.dumps({"policy": policy, "seed": seed, "meta": meta}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def _epoch_seed(seed: int, epoch: int) -> int:
    return int(np.random.SeedSequence([seed, epoch]).generate_state(1)[0])


def _save(obj: dict, path: Path) -> None:
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def train(policy: dict, seed: int, features_path, frames_path, out_dir, threads: int = 1, progress: bool = True,
          on_epoch_end=None) -> pl.DataFrame:
    from ..experiments import saved_epochs

    torch.set_num_threads(threads)
    out_dir = Path(out_dir)
    work = out_dir / ".train"
    device = pick_device(policy["device"])
    tokens, labels, stats, meta = load_data(policy, features_path, frames_path)
    fingerprint = _fingerprint(policy, seed, meta)

    torch.manual_seed(seed)
    model = SequencePolicy(policy, meta["K"], meta["D"]).to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=policy["lr"], weight_decay=policy["weight_decay"])
    history: list[dict] = []
    start = 0
    state_path = work / "state.pt"
    if state_path.is_file():
        state = torch.load(state_path, map_location=device, weights_only=False)
        if state["fingerprint"] == fingerprint:
            model.load_state_dict(state["model"])
            opt.load_state_dict(state["optimizer"])
            history, start = state["history"], state["epoch"]
            log.info("resuming %s after epoch %d", policy.get("name"), start)
        else:
            log.info("discarding resume state of different settings in %s", work)
            shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)

    loader = ChunkWindowLoader(tokens, labels, policy["window"], policy["horizon"], policy["batch_size"],
                               policy["cameras"], seed)
    keep = set(saved_epochs(policy))
    for epoch in range(start, policy["epochs"]):
        torch.manual_seed(_epoch_seed(seed, epoch))
        model.train()
        t0 = time.perf_counter()
        sums = {"loss": 0.0, "loss_joints": 0.0, "loss_gripper": 0.0}
        n = 0
        bar = tqdm(loader.epoch(epoch), total=len(loader), disable=not progress, unit="batch",
                   desc=f"{policy.get('name', 'policy')} epoch {epoch + 1}/{policy['epochs']}")
        for batch in bar:
            batch = {k: v.to(device) for k, v in batch.items()}
            pred = model(batch["tokens"], batch["proprio"], batch["goal"])
            w = loss_weights(policy["loss_weighting"], batch["progress"], epoch, policy["time_weight_warmup_epochs"])
            terms = loss_terms(pred, batch["action"], w, policy["gripper"] == "bce")
            opt.zero_grad(set_to_none=True)
            terms["loss"].backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), policy["grad_clip"])
            opt.step()
            b = len(batch["action"])
            for k in sums:
                sums[k] += float(terms[k].detach()) * b
            n += b
            bar.set_postfix(loss=f"{sums['loss'] / n:.4f}")
        row = {"epoch": epoch + 1, **{k: v / n for k, v in sums.items()}, "lr": policy["lr"],
               "seconds": time.perf_counter() - t0}
        history.append(row)
        log.info("epoch %d: %s", epoch + 1, row)
        state = {"model": model.state_dict(), "optimizer": opt.state_dict(), "policy": policy, "seed": seed,
                 "norm": stats, "meta": meta, "epoch": epoch + 1, "history": history, "fingerprint": fingerprint}
        if epoch + 1 in keep:
            _save(state, work / f"epoch_{epoch + 1:04d}.pt")
        _save(state, state_path)
        if on_epoch_end is not None:
            on_epoch_end(epoch + 1)

    table = pl.DataFrame(history)
    with atomic_path(out_dir / "checkpoints") as tmp:
        tmp.mkdir()
        for e in sorted(keep):
            os.link(work / f"epoch_{e:04d}.pt", tmp / f"epoch_{e:04d}.pt")
    with atomic_path(out_dir / "train_log.parquet") as tmp:
        table.write_parquet(tmp)
    shutil.rmtree(work)
    return table


def load_policy(path, device: str | torch.device = "cpu"):
    """A saved checkpoint -> (model in eval mode, normalization stats, policy settings, meta)."""
    ckpt = torch.load(path, map_location=device, weights_only=False)
    model = SequencePolicy(ckpt["policy"], ckpt["meta"]["K"], ckpt["meta"]["D"]).to(device)
    model.load_state_dict(ckpt["model"])
    model.eval()
    stats = {k: np.asarray(v) for k, v in ckpt["norm"].items()}
    return model, stats, ckpt["policy"], ckpt["meta"]
