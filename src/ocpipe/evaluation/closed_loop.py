"""Closed-loop evaluation of a policy checkpoint (docs/study.md, Evaluation protocol).

Each step renders the training cameras, encodes them with the same frozen encoder, and keeps a window of the
last T steps (the first step repeated at the start, as in training). Every `execute_actions` steps the policy is
queried and the first `execute_actions` of its H predicted actions are executed. An episode ends at the first
success or at the episode cap. Successes in fewer than `trivial_steps` steps are flagged trivial (they say
nothing about the policy) and left out of the success rate."""

from __future__ import annotations

import logging
import time
from collections import deque
from pathlib import Path

import numpy as np
import polars as pl
import torch
from tqdm import tqdm

from ..encoders import registry
from ..features.encode import sha256
from ..frames.store import open_store
from ..policy import observation
from ..policy.checkpoint import load_policy
from ..policy.settings import PolicySettings
from ..sim import envs
from ..util.devices import to_device
from . import replay

log = logging.getLogger(__name__)


def check_checkpoint(checkpoint, policy: PolicySettings | dict, meta: dict, frames_store, encoder_checkpoint,
                     expected: dict | None = None) -> None:
    """Refuse a policy checkpoint that does not belong with this job's inputs, before a simulator is built:
    ``expected`` (the resolved settings of the experiment being evaluated) names another task, camera set,
    resolution or encoder; the checkpoint was trained on another encoder's features; the frames store (its
    cameras and calibration) is of another task, camera set or resolution; or the encoder weights differ."""
    policy = PolicySettings.of(policy)
    if expected is not None:
        for key in ("task", "encoder", "cams", "resolution"):
            got = getattr(policy.stores, key)
            if got != expected.get(key):
                raise ValueError(
                    f"{checkpoint}: trained for {key} {got!r}, but experiment {expected.get('name')!r} "
                    f"has {key} {expected.get(key)!r}: the checkpoint belongs to another experiment; retrain "
                    f"(delete {Path(checkpoint).parent} and rerun the workflow)")
    if meta.get("encoder") not in (None, policy.stores.encoder):
        raise ValueError(
            f"{checkpoint}: its policy names encoder {policy.stores.encoder!r} but it was trained on "
            f"{meta['encoder']!r} features ({meta.get('features_store')}): delete that features store and the run's "
            "checkpoints and rerun the workflow to rebuild and retrain")
    attrs = open_store(frames_store).attrs.asdict()
    for key, attr in (("task", "task"), ("cams", "camera_set"), ("resolution", "resolution")):
        got = getattr(policy.stores, key)
        if attr in attrs and got != attrs[attr]:
            raise ValueError(
                f"{checkpoint}: trained for {key} {got!r}, but {frames_store} is a frames store of "
                f"{attr} {attrs[attr]!r}: give the frames store it was trained on ({meta.get('frames_store')})")
    if encoder_checkpoint and meta.get("encoder_checkpoint_sha256") not in (None, sha256(encoder_checkpoint)):
        raise ValueError(f"{encoder_checkpoint} is not the encoder checkpoint that {checkpoint} was trained on "
                         "(sha256 differs): rebuild the features store and retrain")


def check_state_tokens(checkpoint, meta: dict, encoder) -> None:
    """A control trained on state tokens of one layout (encoders.state) cannot read another's."""
    if encoder.dims != meta["D"]:
        raise ValueError(
            f"{checkpoint}: trained on {meta['D']}-dim state tokens, but encoders.state.tcp_relative = "
            f"{encoder.tcp_relative} makes {encoder.dims}-dim ones: set it back, or rerun the workflow to rebuild "
            "the state features store and retrain")


def cameras_to_render(policy: PolicySettings, reads_labels: bool) -> list[str]:
    """What a step must render: the cameras the policy reads; every camera of the set where the exact 2d goal takes
    their live matrices; nothing for an encoder that reads the simulator's state. A camera is about a fifth of a
    step's CPU time (bench/profile_eval.py)."""
    names = list(envs.CAMERA_SETS[policy.stores.cams])
    if reads_labels:
        return []
    if policy.goal.kind == "2d" and policy.goal.calibration == "exact":
        return names
    return [names[i] for i in policy.stores.cameras]


def policy_env(policy: PolicySettings | dict, config: dict, reads_labels: bool):
    """The environment a policy is evaluated in: its task, camera set, resolution, the sim's shader and robot
    visuals, rendering what cameras_to_render says (nothing for an encoder that reads the simulator's state)."""
    policy = PolicySettings.of(policy)
    rendered = cameras_to_render(policy, reads_labels)
    return envs.make_env(policy.stores.task, config, policy.stores.cams if rendered else None,
                         policy.stores.resolution, obs_mode="rgb", cameras=rendered)


class ClosedLoop:
    """One environment + the frozen encoder + one policy checkpoint.

    ``expected``: the settings of the experiment the checkpoint is evaluated for; see check_checkpoint."""

    def __init__(self, checkpoint: str | Path, config: dict, frames_store: str | Path,
                 encoder_checkpoint: str | Path | None, device: str = "cpu", expected: dict | None = None):
        self.device = torch.device(device)
        self.model, self.policy, self.meta = load_policy(checkpoint, self.device)
        p = self.policy
        check_checkpoint(checkpoint, p, self.meta, frames_store, encoder_checkpoint, expected)
        read = list(p.stores.cameras)
        self.encoder = to_device(registry.build(p.stores.encoder, config["encoders"], frames_store, encoder_checkpoint,
                                                cameras=read), self.device)
        self.reads_labels = getattr(self.encoder, "reads_labels", False)
        if self.reads_labels:
            check_state_tokens(checkpoint, self.meta, self.encoder)
        self.task = p.stores.task
        # the 2d goal is projected into every camera of the set (as in training), the tokens come from those read
        self.camera_names = list(envs.CAMERA_SETS[p.stores.cams])
        self.uids = [envs.SIM_CAMERA_UID[c] for c in self.camera_names]
        self.read_uids = [self.uids[i] for i in read]
        self.env = policy_env(p, config, self.reads_labels)
        self.approx = envs.approx_camera_matrices(config, self.camera_names, p.stores.resolution)
        ev = config["evaluation"]
        self.cap = ev["episode_cap"][self.task]
        self.execute = min(ev["execute_actions"], p.network.horizon)
        self.ensemble = ev["temporal_ensemble"]
        self.readout_filter = ev["readout_filter"]
        self.trivial_steps = ev["trivial_steps"]

    def close(self) -> None:
        self.env.close()

    def settings(self) -> dict:
        """The evaluation settings this loop runs with, recorded in every episode row it produces."""
        return {"episode_cap": self.cap, "execute_actions": self.execute, "temporal_ensemble": float(self.ensemble),
                "readout_filter": self.readout_filter, "trivial_steps": self.trivial_steps}

    def _tokens(self, obs, labels: dict) -> torch.Tensor:
        """This step's visual tokens (C, K, D), exactly as the policy saw them in training."""
        if self.reads_labels:
            return torch.from_numpy(self.encoder.tokens_from_labels(labels))[self.policy.stores.cameras]
        rgb = torch.stack([obs["sensor_data"][u]["rgb"][0] for u in self.read_uids])[None].cpu()
        tokens, _ = self.encoder.encode(rgb.to(self.device))  # built for the cameras read, in the policy's order
        return observation.as_stored(tokens.cpu(), self.meta.get("tokens_dtype", "float32"))[0]

    @torch.inference_mode()
    def _observe(self, obs, first: bool, info: dict | None = None) -> tuple[torch.Tensor, np.ndarray, np.ndarray,
                                                                            dict]:
        """-> this step's raw inputs (tokens (C, K, D), proprio (P,), goal (G,)) and its labels; ``info``: what
        the step that led here returned."""
        rows = observation.step_labels(self.env, first, info)
        labels = {k: v[0] for k, v in rows.items()}
        cameras = observation.step_cameras(self.policy, obs, self.uids, self.approx)
        return (self._tokens(obs, labels), observation.proprio(self.policy, rows)[0],
                observation.goal(self.policy, rows, cameras)[0], labels)

    @torch.inference_mode()
    def object_pose(self, tokens: torch.Tensor) -> torch.Tensor | None:
        """The policy's object read-out of this step's tokens: the standardized pose (5,), None without a read-out."""
        if self.model.object_readout is None:
            return None
        return self.model.object_pose(tokens.to(self.device)).cpu()

    def true_pose(self, labels: dict) -> torch.Tensor:
        """The simulator's object pose, standardized as the read-out's: the read-out a perfect perception gives."""
        pose = observation.object_pose({k: np.asarray(labels[k])[None] for k in ("obj_pos", "obj_quat")})[0]
        return self.model.normalizer.pose(torch.from_numpy(pose).to(self.device)).cpu()

    def object_position(self, pose: torch.Tensor | None) -> list[float]:
        """A standardized read-out pose -> the object's position (m; NaN without a read-out): logged per step, so
        the closed-loop perception error can be set beside the probes'."""
        if pose is None:
            return [float("nan")] * 3
        return self.model.normalizer.pose.invert(pose.to(self.device))[:3].cpu().numpy().astype(float).tolist()

    @torch.inference_mode()
    def episode(self, seed: int) -> tuple[dict, dict[str, list]]:
        obs, _ = self.env.reset(seed=seed)
        T = self.policy.network.window
        window: deque = deque(maxlen=T)
        steps: dict[str, list] = {k: [] for k in ("step", "action", "is_grasped", "tcp_pos", "goal_pos", "obj_pos",
                                                   "obj_est", "obj_seen", "reward", "state")}
        chunks: deque = deque(maxlen=-(-self.policy.network.horizon // self.execute))  # (query step, (H, 8) actions)
        success, total, info = False, 0.0, None
        for t in range(self.cap):
            tokens, proprio, goal, labels = self._observe(obs, first=t == 0, info=info)
            pose = self.object_pose(tokens)
            seen = self.true_pose(labels) if self.readout_filter == "true_pose" and pose is not None else pose
            window.append((tokens, proprio, goal, seen if seen is not None else torch.zeros(0)))
            while len(window) < T:
                window.appendleft(window[0])
            if t % self.execute == 0:  # execute <= H: a chunk always covers the steps until the next query
                batch = [torch.stack([torch.as_tensor(w[i]) for w in window])[None].to(self.device) for i in range(4)]
                # each step's read-out as computed when its frame arrived (or the true pose): not recomputed
                out = self.model(*batch[:3], readout_seen=batch[3] if seen is not None else None)
                qpos = torch.from_numpy(labels["qpos"])[None].to(self.device)
                chunks.append((t, self.model.normalizer.actions_from_model(out.actions, qpos)[0].cpu().numpy()))
            if self.ensemble:
                action = ensemble_action(chunks, t, self.ensemble)
            else:
                t0, chunk = chunks[-1]
                action = chunk[t - t0]
            obs, reward, _, _, info = self.env.step(torch.as_tensor(action[None]))
            reward = float(reward[0])
            total += reward
            # the state after the step, so the episode replays checked step by step (evaluation/replay.py): 70
            # floats, ~0.15 ms of CPU against ~47 ms for the step (docs/results.md: CPU ms per closed-loop step)
            state = replay.env_state(self.env)
            for k, v in (("step", t), ("action", action.tolist()), ("is_grasped", labels["is_grasped"]),
                         ("tcp_pos", labels["tcp_pos"].tolist()), ("goal_pos", labels["goal_pos"].tolist()),
                         ("obj_pos", labels["obj_pos"].tolist()), ("obj_est", self.object_position(pose)),
                         ("obj_seen", self.object_position(seen)), ("reward", reward), ("state", state)):
                steps[k].append(v)
            if bool(info["success"][0]):
                success = True
                break
        n = len(steps["step"])
        row = {"seed": seed, "success": success, "steps": n, "trivial": success and n < self.trivial_steps,
               "return": total}
        return row, steps


def ensemble_action(chunks, t: int, decay: float) -> np.ndarray:
    """Temporal ensembling of action chunks: every earlier prediction that covers step ``t`` votes, the oldest
    weighted most (exp(-decay * i), i = 0 for the oldest), so a new query bends the motion instead of jumping.
    Joints are averaged; the gripper command is the sign of the weighted vote."""
    covering = [chunk[t - t0] for t0, chunk in chunks if 0 <= t - t0 < len(chunk)]
    w = np.exp(-decay * np.arange(len(covering)))[:, None]
    mean = (w * np.stack(covering)).sum(0) / w.sum()
    action = mean.astype(np.float32)
    action[7] = 1.0 if mean[7] >= 0 else -1.0
    return action


def run(loop: ClosedLoop, seeds: list[int], ids: dict, progress: bool = True) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Episodes for ``seeds`` -> (one row per episode, one row per step); ``ids`` (exp, checkpoint, run) tag rows."""
    rows, step_frames = [], []
    t0 = time.perf_counter()
    bar = tqdm(seeds, desc=f"eval {ids}", unit="episode", disable=not progress)
    for seed in bar:
        row, steps = loop.episode(seed)
        rows.append({**ids, **loop.settings(), **row})
        step_frames.append(pl.DataFrame({**{k: [v] * len(steps["step"]) for k, v in ids.items()},
                                         "seed": [seed] * len(steps["step"]), **steps},
                                        schema_overrides={"state": pl.List(pl.Float32)}))
        sr = np.mean([r["success"] and not r["trivial"] for r in rows])
        bar.set_postfix(sr=f"{sr:.2f}")
    log.info("%d episodes in %.1f s", len(seeds), time.perf_counter() - t0)
    return pl.DataFrame(rows), pl.concat(step_frames, how="vertical")
