"""Training one experiment: set up (data, model, Normalizer, read-out, resume state), the epoch loop, publish.

Layout under ``out_dir`` (results/runs/{exp}):
  checkpoints/epoch_{E:04d}.pt  every save_every epochs and the last (policy.checkpoint)
  train_log.parquet             one row per epoch: epoch, the losses, lr, seconds, the open-loop error
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
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl
import torch
from tqdm import tqdm

from ..features.scenes import open_scenes
from ..util.atomic import atomic_path
from ..util.devices import pick_device
from . import checkpoint, data, readout
from .model import loss_terms, parameter_count
from .settings import PolicySettings
from .weighting import loss_weights
from .windows import action_frames

log = logging.getLogger(__name__)
LOSSES = ("loss", "loss_joints", "loss_gripper", "loss_aux", "loss_readout")


@dataclass
class Run:
    """Everything one training needs between its steps."""

    policy: PolicySettings
    seed: int
    data: data.TrainingData
    model: torch.nn.Module
    opt: torch.optim.Optimizer
    device: torch.device
    work: Path
    fingerprint: str
    history: list
    start: int  # epochs already done (resumed)


def train(policy: PolicySettings | dict, seed: int, features_path, frames_path, out_dir, threads: int = 1,
          progress: bool = True, on_epoch_end=None, scenes_path=None, camera_approx: dict | None = None
          ) -> pl.DataFrame:
    """Train ``policy`` on the stores and publish its checkpoints and log under ``out_dir`` -> the log."""
    from ..config.experiments import saved_epochs

    policy = PolicySettings.of(policy)
    torch.set_num_threads(threads)
    run = set_up(policy, seed, features_path, frames_path, Path(out_dir), scenes_path, camera_approx)
    keep = set(saved_epochs(policy.as_dict()))
    for epoch in range(run.start, policy.training.epochs):
        run.history.append(train_epoch(run, epoch, progress))
        log.info("epoch %d: %s", epoch + 1, run.history[-1])
        state = {"model": run.model.state_dict(), "optimizer": run.opt.state_dict(), "policy": policy.as_dict(),
                 "seed": seed, "meta": run.data.meta, "epoch": epoch + 1, "history": run.history,
                 "fingerprint": run.fingerprint, "parameters": parameter_count(run.model)}
        if epoch + 1 in keep:
            checkpoint.save(state, run.work / f"epoch_{epoch + 1:04d}.pt")
        checkpoint.save(state, run.work / "state.pt")
        if on_epoch_end is not None:
            on_epoch_end(epoch + 1)
    return publish(run.history, run.work, Path(out_dir), keep)


def set_up(policy: PolicySettings, seed: int, features_path, frames_path, out_dir: Path, scenes_path,
           camera_approx) -> Run:
    """Data, the seeded model with its fitted Normalizer (and frozen read-out), the optimizer, and the resume
    state of an interrupted run of the same settings."""
    device = pick_device(policy.training.device)
    d = data.load(policy, features_path, frames_path, camera_approx)
    scenes = None
    if policy.readout.scenes:
        if scenes_path is None:
            raise ValueError(f"policy {policy.name!r} has readout_scenes: true but no scenes store was given")
        scenes = open_scenes(scenes_path, d.meta["encoder_checkpoint_sha256"])
    meta = d.meta if scenes is None else {**d.meta, "scenes_store": str(scenes_path)}
    blob = json.dumps({"policy": policy.as_dict(), "seed": seed, "meta": meta}, sort_keys=True, default=str)
    fingerprint = hashlib.sha256(blob.encode()).hexdigest()
    work = out_dir / ".train"
    state_path = work / "state.pt"
    state = torch.load(state_path, map_location=device, weights_only=False) if state_path.is_file() else None
    if state is not None and state["fingerprint"] != fingerprint:
        log.info("discarding resume state of different settings in %s", work)
        shutil.rmtree(work)
        state = None

    torch.manual_seed(seed)
    model = checkpoint.build_model(policy, d.meta).to(device)
    if state is None:
        model.normalizer.fit(policy, **d.normalizer_inputs(policy))
        readout.fit_tokens(model.normalizer, policy, d.tokens, d.train_frames)
        if scenes is not None:
            readout.fit_readout(model, policy, d.tokens, d.labels.readout, d.train_frames, scenes, seed)
    elif scenes is not None:  # the fitted read-out comes back with the resume state: freeze it, do not refit
        model.object_readout.requires_grad_(False)
    opt = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=policy.training.lr,
                            weight_decay=policy.training.weight_decay)
    history, start = [], 0
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        history, start = state["history"], state["epoch"]
        log.info("resuming %s after epoch %d", policy.name, start)
    work.mkdir(parents=True, exist_ok=True)
    return Run(policy, seed, d, model, opt, device, work, fingerprint, history, start)


def learning_rate(training, step: int, steps_per_epoch: int) -> float:
    """The learning rate of global ``step`` (0-based): a pure function of the step, so a resumed run follows the
    same schedule without a scheduler's state."""
    if training.lr_schedule == "constant":
        return training.lr
    if step < steps_per_epoch:  # linear warm-up over the first epoch
        return training.lr * (step + 1) / steps_per_epoch
    total = training.epochs * steps_per_epoch
    done = (step - steps_per_epoch) / max(1, total - steps_per_epoch)
    return training.lr * 0.5 * (1 + math.cos(math.pi * done))


def _epoch_seed(seed: int, epoch: int) -> int:
    return int(np.random.SeedSequence([seed, epoch]).generate_state(1)[0])


def train_epoch(run: Run, epoch: int, progress: bool) -> dict:
    """One pass over the training windows -> the epoch's log row (mean losses, open-loop error)."""
    policy, model, d = run.policy, run.model, run.data
    torch.manual_seed(_epoch_seed(run.seed, epoch))
    model.train()
    loader = d.windows(policy, d.train_frames, policy.training.batch_size, run.seed,
                       every_step=policy.training.action_loss == "every_step")
    readout_w = readout.readout_weights(policy.readout.yaw_weight, run.device)
    t0 = time.perf_counter()
    sums, n = dict.fromkeys(LOSSES, 0.0), 0
    # every_step epochs differ in length by a few batches; the schedule reads this epoch's as every epoch's, so it
    # still runs from the warm-up through the cosine to 0 at the last batch
    batches = loader.batches(epoch)
    bar = tqdm(loader.epoch(epoch), total=batches, disable=not progress, unit="batch",
               desc=f"{policy.name or 'policy'} epoch {epoch + 1}/{policy.training.epochs}")
    for step, batch in enumerate(bar):
        lr = learning_rate(policy.training, epoch * batches + step, batches)
        for group in run.opt.param_groups:
            group["lr"] = lr
        batch = {k: v.to(run.device) for k, v in batch.items()}
        terms = batch_loss(model, policy, batch, epoch, readout_w)
        run.opt.zero_grad(set_to_none=True)
        terms["loss"].backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), policy.training.grad_clip)
        run.opt.step()
        b = len(batch["action"])
        for k in sums:
            sums[k] += float(terms[k].detach()) * b
        n += b
        bar.set_postfix(loss=f"{sums['loss'] / n:.4f}")
    row = {"epoch": epoch + 1, **{k: v / n for k, v in sums.items()}, "lr": lr,
           "seconds": time.perf_counter() - t0}
    if len(d.val_frames):
        row |= openloop_error(model, d, policy, run.device, run.seed)
    return row


def batch_loss(model, policy: PolicySettings, batch: dict, epoch: int, readout_w: torch.Tensor) -> dict:
    """The loss terms of one batch: the weighted action loss, plus the auxiliary head's and the read-out's (each
    0 without that head)."""
    every_step = "step_mask" in batch
    out = model(batch["tokens"], batch["proprio"], batch["goal"], every_step=every_step)
    norm = model.normalizer
    tr = policy.training
    w = loss_weights(tr.loss_weighting, batch["progress"], epoch, tr.time_weight_warmup_epochs)
    pred, action, qpos = out.actions, batch["action"], batch.get("qpos")
    if every_step:  # (B, T, H, 8) -> (B * T, H, 8); the loss is the mean over the steps the mask keeps
        mask = batch["step_mask"].flatten().to(w.dtype)
        w = w.flatten(0, 1) * (mask * len(mask) / mask.sum())[:, None, None]
        pred, action = pred.flatten(0, 1), action.flatten(0, 1)
        qpos = None if qpos is None else qpos.flatten(0, 1)
    terms = loss_terms(pred, norm.actions_to_model(action, qpos), w, policy.network.gripper == "bce")
    terms["loss_aux"] = torch.zeros(())
    if out.object_pos is not None:
        terms["loss_aux"] = ((out.object_pos - norm.aux(batch["aux"])) ** 2).mean()
        terms["loss"] = terms["loss"] + policy.training.aux_object_weight * terms["loss_aux"]
    terms["loss_readout"] = torch.zeros(())
    if out.readout is not None:  # its own loss: the policy's tokens see the read-out without gradient
        terms["loss_readout"] = (readout_w * (out.readout - norm.pose(batch["readout"])) ** 2).mean()
        terms["loss"] = terms["loss"] + terms["loss_readout"]
    return terms


def publish(history: list, work: Path, out_dir: Path, keep: set) -> pl.DataFrame:
    """Move the kept checkpoints and the log into place (each atomically) and drop the work folder."""
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
def openloop_error(model, d: data.TrainingData, policy: PolicySettings, device, seed: int = 0) -> dict:
    """Action error on held-out demo frames, without a simulator: the predicted H-step chunk against the expert's
    (joint error in radians, mean over joints and steps, and for the first step alone; share of gripper commands
    that agree). Cheap, and it separates 'did not learn the demos' from 'fails in closed loop'."""
    loader = d.windows(policy, d.val_frames, 256, seed)
    model.eval()
    joint_err, first_err, grip_ok, n = 0.0, 0.0, 0.0, 0
    for batch in loader.epoch(0):
        frames = batch["frame"].numpy()
        out = model(batch["tokens"].to(device), batch["proprio"].to(device), batch["goal"].to(device))
        got = model.normalizer.actions_from_model(out.actions, batch["qpos"].to(device)).cpu().numpy()
        want = d.labels.action[action_frames(frames, d.labels, policy.network.horizon)]
        err = np.abs(got[..., :7] - want[..., :7])
        joint_err += float(err.mean(axis=(1, 2)).sum())
        first_err += float(err[:, 0].mean(axis=1).sum())
        grip_ok += float((np.sign(got[..., 7]) == np.sign(want[..., 7])).mean(axis=1).sum())
        n += len(frames)
    model.train()
    return {"val_joint_err_rad": joint_err / n, "val_first_joint_err_rad": first_err / n,
            "val_gripper_agree": grip_ok / n}
