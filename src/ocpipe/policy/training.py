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
import math
import os
import shutil
import time
from pathlib import Path

import numpy as np
import polars as pl
import torch
from tqdm import tqdm

from ..encoders.state import state_tokens
from ..features.encode import PolicyTokens, check_provenance, open_features
from ..features.probes import fit_mse
from ..features.scenes import open_scenes
from ..frames.store import open_store
from ..sim import envs, projection
from ..util.atomic import atomic_path
from ..util.devices import pick_device
from . import normalization
from .model import SequencePolicy, loss_terms
from .settings import PolicySettings
from .weighting import loss_weights
from .windows import ChunkWindowLoader, Labels, action_frames

log = logging.getLogger(__name__)


def goal_source(policy: PolicySettings | dict) -> str | None:
    """The frames-store array a policy's goal input comes from (None: no goal input)."""
    policy = PolicySettings.of(policy)
    return {"none": None, "3d": "goal_pos"}.get(policy.goal, f"goal2d_{policy.goal_calibration}")


def goal_array(frames, policy: PolicySettings | dict, camera_approx: dict | None = None) -> np.ndarray:
    """The goal input of every frame, before goal_norm: the goal, and with `goal_relative: tcp` the goal minus the
    TCP beside it, the TCP projected like the goal (2d: into each camera with the same calibration; the approx
    model comes from ``camera_approx``, config `camera_approx`)."""
    policy = PolicySettings.of(policy)
    source = goal_source(policy)
    if source is None:
        return np.zeros((frames["qpos"].shape[0], 0), dtype=np.float32)
    goal = frames[source][:].astype(np.float32)
    if policy.goal == "2d" and not np.isfinite(goal).all():
        raise ValueError(f"{source} has NaN in {frames.store}: the camera set "
                         f"{policy.cams!r} has no {policy.goal_calibration} 2d goal (policy.goal_calibration)")
    if policy.goal_relative != "tcp":
        return goal
    hand = frames["tcp_pos"][:].astype(np.float32)
    if policy.goal == "2d":
        hand = projection.goal2d(hand, *_goal_cameras(frames, policy, camera_approx), frames.attrs["resolution"])
    return np.concatenate([goal, goal - hand], axis=1).astype(np.float32)


def _goal_cameras(frames, policy: PolicySettings, camera_approx: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsics and extrinsics the store's 2d goal was projected with."""
    if policy.goal_calibration == "approx":
        if camera_approx is None:
            raise ValueError(f"policy {policy.name!r}: goal_relative tcp with the approx 2d goal needs config "
                             "camera_approx")
        return envs.approx_camera_matrices({"camera_approx": camera_approx}, list(frames.attrs["cameras"]),
                                           frames.attrs["resolution"])
    suffix = "_per_frame" if "cam_intrinsic_per_frame" in frames else ""  # a moving (hand) camera
    names = ("cam_intrinsic" + suffix, "cam_extrinsic" + suffix)
    missing = [n for n in names if n not in frames]
    if missing:
        raise ValueError(f"{frames.store}: frames store has no {missing}, which policy {policy.name!r} needs to "
                         "project the TCP (goal_relative: tcp); rerun the workflow to rebuild the store")
    return tuple(frames[n][:] for n in names)


def split_episodes(offsets, val_episodes: int, source: str = "") -> tuple[np.ndarray, np.ndarray]:
    """-> (training frames, validation frames): the last ``val_episodes`` episodes are held out for the open-loop
    check and never trained on."""
    offsets = np.asarray(offsets, dtype=np.int64)
    E = len(offsets) - 1
    if val_episodes >= E:
        raise ValueError(f"policy.val_episodes is {val_episodes} but {source} has only {E} episodes")
    cut = offsets[E - val_episodes]
    return np.arange(cut), np.arange(cut, offsets[-1])


def gather_tokens(tokens, frames: np.ndarray, block: int = 1024) -> np.ndarray:
    """The tokens of sorted frame ids ``frames``, read a block of frames at a time (a token store decompresses
    whole chunks: one read per frame would decompress a chunk per frame)."""
    return np.concatenate([tokens[lo : lo + block][frames[(frames >= lo) & (frames < lo + block)] - lo]
                           for lo in range(0, int(frames[-1]) + 1, block)])


def readout_weights(yaw_weight: float, device=None) -> torch.Tensor:
    """The object read-out's per-output loss weights: position 1, the yaw's sin/cos ``yaw_weight``."""
    return torch.tensor([1.0, 1.0, 1.0, yaw_weight, yaw_weight], device=device)


def element_stats(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean/std of every element of (N, ...) inputs, flattened per sample."""
    x = x.reshape(len(x), -1).astype(np.float64)
    return x.mean(0).astype(np.float32), np.maximum(x.std(0), normalization.EPS).astype(np.float32)


def fit_readout(model, tokens, readout_targets: np.ndarray, train_frames: np.ndarray, scenes, stats: dict,
                cameras: list[int], seed: int, yaw_weight: float = 1.0, epochs: int = 40, batch: int = 256) -> float:
    """Fit the policy's object read-out on the training demos' frames plus the scenes store's scenes (the same
    pose targets, standardized as for the demos), then freeze it: the policy trains around a fixed estimate of
    where the object is, fitted on far more placements than the demos show. -> the last batch's loss."""
    cams = list(cameras)
    demo = gather_tokens(tokens, train_frames)[:, cams].astype(np.float32)
    pose = state_tokens(scenes["obj_pos"][...], scenes["obj_quat"][...])[:, 0, 0]
    y = np.concatenate([readout_targets[train_frames], (pose - stats["readout_mean"]) / stats["readout_std"]])
    x = np.concatenate([demo, scenes["tokens"][...][:, cams].astype(np.float32)])
    device = model.token_mean.device
    if model.readout_elementwise:  # the input statistics of what the read-out is fitted on: demos and scenes
        mean, std = element_stats(x)
        stats["readout_in_mean"], stats["readout_in_std"] = mean, std
        model.readout_in_mean.copy_(torch.from_numpy(mean))
        model.readout_in_std.copy_(torch.from_numpy(std))
    with torch.no_grad():
        xz = model.readout_input(torch.from_numpy(x).to(device))
    yt = torch.from_numpy(y.astype(np.float32)).to(device)
    readout = model.object_readout
    loss = fit_mse(readout, xz, yt, torch.Generator().manual_seed(seed), epochs, batch,
                   weights=readout_weights(yaw_weight, device))
    readout.requires_grad_(False)
    log.info("object read-out fitted on %d demo frames and %d scenes, then frozen (loss %.4f)", len(demo),
             len(x) - len(demo), loss)
    return loss


def _spread(frames: np.ndarray, max_frames: int = 20000) -> np.ndarray:
    """At most ``max_frames`` evenly spaced of ``frames``."""
    return frames[np.unique(np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int))]


def token_stats(tokens, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-dimension mean/std of the visual tokens (pooled over cameras and slots) on evenly spaced training frames."""
    x = gather_tokens(tokens, _spread(frames))
    return element_stats(x.reshape(-1, x.shape[-1]))


def load_data(policy: PolicySettings | dict, features_path, frames_path, camera_approx: dict | None = None):
    """-> (tokens array, Labels, normalization stats computed from the training frames, meta, (train, val) frames).
    ``camera_approx`` (config `camera_approx`): only for a goal_relative policy on the approx 2d goal."""
    policy = PolicySettings.of(policy)
    goal = (goal_source(policy),) if policy.goal != "none" else ()
    reads_obj = policy.aux_object_weight > 0 or policy.object_readout
    aux = ("obj_pos",) * reads_obj + ("obj_quat",) * policy.object_readout
    reads_tcp = policy.proprio == "joints7_tcp" or policy.readout_tcp_relative or policy.goal_relative == "tcp"
    tcp = ("tcp_pos",) * reads_tcp
    feats, frames = open_features(features_path), open_store(frames_path, need=("qpos", "action", *goal, *aux, *tcp))
    check_provenance(feats, features_path, frames, frames_path)
    tokens = PolicyTokens(feats, policy.slot_geometry, str(features_path))
    if tokens.shape[0] != frames["qpos"].shape[0]:
        raise ValueError(
            f"{features_path} has {tokens.shape[0]} frames but {frames_path} has {frames['qpos'].shape[0]}"
        )
    if max(policy.cameras) >= tokens.shape[1]:
        raise ValueError(f"policy.cameras {policy.cameras}: {features_path} has {tokens.shape[1]} cameras")
    offsets = frames.attrs["episode_offsets"]
    train_frames, val_frames = split_episodes(offsets, policy.val_episodes, str(frames_path))
    qpos, action = frames["qpos"][:].astype(np.float32), frames["action"][:].astype(np.float32)
    tcp_pos = frames["tcp_pos"][:].astype(np.float32) if reads_tcp else None
    proprio_x = normalization.proprio_input(qpos, tcp_pos, policy.proprio)
    stats = normalization.compute(proprio_x[train_frames], action[train_frames], policy.proprio)
    extra = {}
    if policy.joint_targets == "residual":
        bounds = Labels.from_offsets(offsets, qpos, qpos, action)
        stats.update(
            normalization.residual_stats(
                action, qpos, train_frames, action_frames(train_frames, bounds, policy.horizon)
            )
        )
        extra["residual"] = (normalization.residual_base(qpos), stats["action_mean"], stats["action_std"])
        model_action = action
    else:
        model_action = normalization.action_to_model(action, stats)
    obj = frames["obj_pos"][:].astype(np.float32) if reads_obj else None
    if policy.aux_object_weight > 0:
        stats["aux_mean"], stats["aux_std"] = obj[train_frames].mean(0), np.maximum(obj[train_frames].std(0), 1e-6)
        extra["aux"] = ((obj - stats["aux_mean"]) / stats["aux_std"]).astype(np.float32)
    if policy.object_readout:
        pose = state_tokens(obj, frames["obj_quat"][:])[:, 0, 0]
        stats["readout_mean"] = pose[train_frames].mean(0)
        stats["readout_std"] = np.maximum(pose[train_frames].std(0), 1e-6)
        extra["readout"] = ((pose - stats["readout_mean"]) / stats["readout_std"]).astype(np.float32)
        if policy.readout_tcp_relative:
            extra["tcp"] = tcp_pos
        if policy.readout_standardize == "element" and not policy.readout_scenes:  # else fit_readout sets them
            stats["readout_in_mean"], stats["readout_in_std"] = element_stats(
                gather_tokens(tokens, _spread(train_frames))[:, list(policy.cameras)])
    if policy.first_frame:
        starts = np.asarray(offsets[:-1], dtype=np.int64)
        extra["first"] = (starts, gather_tokens(tokens, starts).astype(np.float32))
    if policy.token_norm == "zscore":
        stats["token_mean"], stats["token_std"] = token_stats(tokens, train_frames)
    goal = goal_array(frames, policy, camera_approx)
    if policy.goal_norm == "zscore" and goal.shape[1]:
        stats["goal_mean"] = goal[train_frames].mean(0)
        stats["goal_std"] = np.maximum(goal[train_frames].std(0), normalization.EPS)
    labels = Labels.from_offsets(
        offsets, normalization.proprio(proprio_x, stats), normalization.goal(goal, stats), model_action, **extra
    )
    meta = {
        "K": int(tokens.shape[2]),
        "D": int(tokens.shape[3]),
        "features_store": str(features_path),
        "frames_store": str(frames_path),
        "encoder": feats.attrs.get("encoder"),
        "encoder_checkpoint_sha256": feats.attrs.get("checkpoint_sha256"),
        "cameras": [frames.attrs["cameras"][c] for c in policy.cameras],
        "tokens_dtype": str(tokens.dtype),
    }
    return tokens, labels, stats, meta, (train_frames, val_frames)


def build_model(policy: PolicySettings | dict, meta: dict, stats: dict) -> SequencePolicy:
    token = (stats["token_mean"], stats["token_std"]) if "token_mean" in stats else None
    readout = (stats["readout_in_mean"], stats["readout_in_std"]) if "readout_in_mean" in stats else None
    pose = (stats["readout_mean"], stats["readout_std"]) if "readout_mean" in stats else None
    return SequencePolicy(policy, meta["K"], meta["D"], token, readout, pose)


def _fingerprint(policy: PolicySettings, seed: int, meta: dict) -> str:
    blob = json.dumps({"policy": policy.as_dict(), "seed": seed, "meta": meta}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def _epoch_seed(seed: int, epoch: int) -> int:
    return int(np.random.SeedSequence([seed, epoch]).generate_state(1)[0])


def learning_rate(policy: PolicySettings | dict, step: int, total_steps: int) -> float:
    """The learning rate of training batch ``step`` of ``total_steps``: a function of the step alone, so a resumed
    run follows the same schedule without any scheduler state."""
    policy = PolicySettings.of(policy)
    if policy.lr_schedule == "cosine":
        return policy.lr * 0.5 * (1.0 + math.cos(math.pi * step / max(total_steps, 1)))
    return policy.lr


def _save(obj: dict, path: Path) -> None:
    # through a file object: given a path, torch.save names the archive inside after the temporary file
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        torch.save(obj, fh)


def train(
    policy: PolicySettings | dict,
    seed: int,
    features_path,
    frames_path,
    out_dir,
    threads: int = 1,
    progress: bool = True,
    on_epoch_end=None,
    scenes_path=None,
    camera_approx: dict | None = None,
) -> pl.DataFrame:
    from ..config.experiments import saved_epochs

    policy = PolicySettings.of(policy)
    torch.set_num_threads(threads)
    out_dir = Path(out_dir)
    work = out_dir / ".train"
    device = pick_device(policy.device)
    tokens, labels, stats, meta, (train_frames, val_frames) = load_data(policy, features_path, frames_path,
                                                                         camera_approx)
    scenes = None
    if policy.readout_scenes:
        if scenes_path is None:
            raise ValueError(f"policy {policy.name!r} has readout_scenes: true but no scenes store was given")
        scenes = open_scenes(scenes_path, meta["encoder_checkpoint_sha256"])
    fingerprint = _fingerprint(policy, seed, meta if scenes is None else {**meta, "scenes_store": str(scenes_path)})

    torch.manual_seed(seed)
    model = build_model(policy, meta, stats).to(device)
    state_path = work / "state.pt"
    state = torch.load(state_path, map_location=device, weights_only=False) if state_path.is_file() else None
    if state is not None and state["fingerprint"] != fingerprint:
        log.info("discarding resume state of different settings in %s", work)
        shutil.rmtree(work)
        state = None
    if scenes is not None:
        if state is None:
            fit_readout(model, tokens, labels.readout, train_frames, scenes, stats, policy.cameras, seed,
                        policy.readout_yaw_weight)
        else:  # the fitted read-out comes back with the resume state: freeze it without fitting it again
            model.object_readout.requires_grad_(False)
    opt = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=policy.lr,
                            weight_decay=policy.weight_decay)
    history: list[dict] = []
    start = 0
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        history, start = state["history"], state["epoch"]
        stats.update(state["norm"])  # what training fitted into them (the scenes read-out's input statistics)
        log.info("resuming %s after epoch %d", policy.name, start)
    work.mkdir(parents=True, exist_ok=True)

    loader = ChunkWindowLoader(
        tokens,
        labels,
        policy.window,
        policy.horizon,
        policy.batch_size,
        policy.cameras,
        seed,
        frames=train_frames,
    )
    val_loader = (
        ChunkWindowLoader(
            tokens, labels, policy.window, policy.horizon, 256, policy.cameras, seed, frames=val_frames
        )
        if len(val_frames)
        else None
    )
    aux_weight = policy.aux_object_weight
    readout_w = readout_weights(policy.readout_yaw_weight, device)
    readout_noise = None
    if policy.object_readout and policy.readout_noise > 0:  # metres -> the read-out's standardized units
        readout_noise = torch.as_tensor(policy.readout_noise / stats["readout_std"][:3], dtype=torch.float32,
                                        device=device)
    proprio_noise = policy.proprio_noise
    keep = set(saved_epochs(policy.as_dict()))
    for epoch in range(start, policy.epochs):
        torch.manual_seed(_epoch_seed(seed, epoch))
        model.train()
        t0 = time.perf_counter()
        sums = {"loss": 0.0, "loss_joints": 0.0, "loss_gripper": 0.0, "loss_aux": 0.0, "loss_readout": 0.0}
        n = 0
        bar = tqdm(
            loader.epoch(epoch),
            total=len(loader),
            disable=not progress,
            unit="batch",
            desc=f"{policy.name or 'policy'} epoch {epoch + 1}/{policy.epochs}",
        )
        for i, batch in enumerate(bar):
            lr = learning_rate(policy, epoch * len(loader) + i, policy.epochs * len(loader))
            for group in opt.param_groups:
                group["lr"] = lr
            batch = {k: v.to(device) for k, v in batch.items()}
            if proprio_noise > 0:  # blur the joint history so the policy cannot act on it alone (copycat)
                batch["proprio"] = batch["proprio"] + proprio_noise * torch.randn_like(batch["proprio"])
            pred, aux = model(batch["tokens"], batch["proprio"], batch["goal"], batch.get("first"), aux=True,
                              readout_noise=readout_noise, tcp=batch.get("tcp"))
            w = loss_weights(policy.loss_weighting, batch["progress"], epoch, policy.time_weight_warmup_epochs)
            terms = loss_terms(pred, batch["action"], w, policy.gripper == "bce")
            terms["loss_aux"] = torch.zeros(())
            if aux["object_pos"] is not None:
                terms["loss_aux"] = ((aux["object_pos"] - batch["aux"]) ** 2).mean()
                terms["loss"] = terms["loss"] + aux_weight * terms["loss_aux"]
            terms["loss_readout"] = torch.zeros(())
            if aux["readout"] is not None:  # its own loss: the policy's tokens see the read-out without gradient
                terms["loss_readout"] = (readout_w * (aux["readout"] - batch["readout"]) ** 2).mean()
                terms["loss"] = terms["loss"] + terms["loss_readout"]
            opt.zero_grad(set_to_none=True)
            terms["loss"].backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), policy.grad_clip)
            opt.step()
            b = len(batch["action"])
            for k in sums:
                sums[k] += float(terms[k].detach()) * b
            n += b
            bar.set_postfix(loss=f"{sums['loss'] / n:.4f}")
        row = {
            "epoch": epoch + 1,
            **{k: v / n for k, v in sums.items()},
            "lr": lr,
            "seconds": time.perf_counter() - t0,
            **(openloop_error(model, val_loader, labels, stats, policy, device) if val_loader else {}),
        }
        history.append(row)
        log.info("epoch %d: %s", epoch + 1, row)
        state = {
            "model": model.state_dict(),
            "optimizer": opt.state_dict(),
            "policy": policy.as_dict(),
            "seed": seed,
            "norm": stats,
            "meta": meta,
            "epoch": epoch + 1,
            "history": history,
            "fingerprint": fingerprint,
        }
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


@torch.inference_mode()
def openloop_error(model, loader: ChunkWindowLoader, labels: Labels, stats: dict,
                   policy: PolicySettings | dict, device) -> dict:
    """Action error on held-out demo frames, without a simulator: the predicted H-step chunk against the expert's
    (joint error in radians, mean over joints and steps, and for the first step alone; share of gripper commands
    that agree). Cheap, and it separates 'did not learn the demos' from 'fails in closed loop'."""
    policy = PolicySettings.of(policy)
    model.eval()
    joint_err, first_err, grip_ok, n = 0.0, 0.0, 0.0, 0
    for batch in loader.epoch(0):
        frames = batch["frame"].numpy()
        inputs = [batch[k].to(device) if k in batch else None for k in ("tokens", "proprio", "goal", "first")]
        pred = model(*inputs, tcp=batch["tcp"].to(device) if "tcp" in batch else None).cpu().numpy()
        qpos = labels.residual[0][frames][:, :7] if labels.residual is not None else None
        got = normalization.action_from_model(pred, stats, qpos=qpos)
        want = labels.action[action_frames(frames, labels, policy.horizon)]
        if labels.residual is None:
            want = normalization.action_from_model(want, stats)
        err = np.abs(got[..., :7] - want[..., :7])
        joint_err += float(err.mean(axis=(1, 2)).sum())
        first_err += float(err[:, 0].mean(axis=1).sum())
        grip_ok += float((np.sign(got[..., 7]) == np.sign(want[..., 7])).mean(axis=1).sum())
        n += len(frames)
    model.train()
    return {
        "val_joint_err_rad": joint_err / n,
        "val_first_joint_err_rad": first_err / n,
        "val_gripper_agree": grip_ok / n,
    }


def load_policy(path, device: str | torch.device = "cpu"):
    """A saved checkpoint -> (model in eval mode, normalization stats, policy settings, meta)."""
    ckpt = torch.load(path, map_location=device, weights_only=False)
    policy = PolicySettings.of(ckpt["policy"])
    model = build_model(policy, ckpt["meta"], ckpt["norm"]).to(device)
    model.load_state_dict(ckpt["model"])
    model.eval()
    stats = {k: np.asarray(v) for k, v in ckpt["norm"].items()}
    return model, stats, policy, ckpt["meta"]
