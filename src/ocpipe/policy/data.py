"""One experiment's training data: the features store's tokens and the frames store's labels, turned into raw
policy inputs and targets by policy.observation, split into training and held-out episodes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..features.encode import check_provenance, open_features
from ..frames.store import open_store
from . import observation
from .settings import PolicySettings
from .windows import ChunkWindowLoader, Labels, action_frames


@dataclass
class TrainingData:
    tokens: object  # the features store's tokens (N, C, K, D), read a chunk at a time
    labels: Labels  # per-frame raw inputs and targets
    train_frames: np.ndarray  # frame ids trained on
    val_frames: np.ndarray  # frame ids of the held-out episodes
    meta: dict  # what the checkpoint records about its inputs

    def windows(self, policy: PolicySettings, frames: np.ndarray, batch_size: int, seed: int,
                every_step: bool = False) -> ChunkWindowLoader:
        """Batches of the policy's T-step windows ending at ``frames``, one features chunk in RAM at a time;
        ``every_step``: windows that supervise each of their steps (ChunkWindowLoader)."""
        return ChunkWindowLoader(self.tokens, self.labels, policy.network.window, policy.network.horizon, batch_size,
                                 policy.stores.cameras, seed, frames=frames, every_step=every_step)

    def normalizer_inputs(self, policy: PolicySettings) -> dict:
        """The training frames' raw inputs and targets that the policy's Normalizer is fitted on."""
        frames, lab = self.train_frames, self.labels
        if policy.training.joint_targets == "residual":  # each target relative to its current frame's joints
            action = lab.action[action_frames(frames, lab, policy.network.horizon)]
        else:
            action = lab.action[frames]
        return {"proprio": lab.proprio[frames], "goal": lab.goal[frames], "action": action,
                "qpos_at": lab.qpos[frames],
                "pose": None if lab.readout is None else lab.readout[frames],
                "aux": None if lab.aux is None else lab.aux[frames]}


def split_episodes(offsets, val_episodes: int, source: str = "") -> tuple[np.ndarray, np.ndarray]:
    """-> (training frames, validation frames): the last ``val_episodes`` episodes are held out for the open-loop
    check and never trained on."""
    offsets = np.asarray(offsets, dtype=np.int64)
    E = len(offsets) - 1
    if val_episodes >= E:
        raise ValueError(f"policy.val_episodes is {val_episodes} but {source} has only {E} episodes")
    cut = offsets[E - val_episodes]
    return np.arange(cut), np.arange(cut, offsets[-1])


def load(policy: PolicySettings | dict, features_path, frames_path, camera_approx: dict | None = None
         ) -> TrainingData:
    """``camera_approx`` (config `camera_approx`): the camera model of the approximate 2d goal."""
    policy = PolicySettings.of(policy)
    feats = open_features(features_path)
    frames = open_store(frames_path, need=observation.labels_needed(policy))
    check_provenance(feats, features_path, frames, frames_path)
    tokens = feats["tokens"]
    if tokens.shape[0] != frames["qpos"].shape[0]:
        raise ValueError(
            f"{features_path} has {tokens.shape[0]} frames but {frames_path} has {frames['qpos'].shape[0]}")
    if max(policy.stores.cameras) >= tokens.shape[1]:
        raise ValueError(f"policy.cameras {policy.stores.cameras}: {features_path} has {tokens.shape[1]} cameras")
    offsets = frames.attrs["episode_offsets"]
    train_frames, val_frames = split_episodes(offsets, policy.training.val_episodes, str(frames_path))
    arrays = {k: frames[k][:] for k in observation.labels_needed(policy)}
    labels = Labels.from_offsets(
        offsets,
        observation.proprio(policy, arrays),
        observation.goal(policy, arrays, observation.store_cameras(policy, frames, camera_approx)),
        arrays["action"].astype(np.float32),
        qpos=arrays["qpos"].astype(np.float32),
        aux=arrays["obj_pos"].astype(np.float32) if policy.training.aux_object_weight > 0 else None,
        readout=observation.object_pose(arrays) if policy.readout.enabled else None,
    )
    meta = {
        "K": int(tokens.shape[2]),
        "D": int(tokens.shape[3]),
        "features_store": str(features_path),
        "frames_store": str(frames_path),
        "encoder": feats.attrs.get("encoder"),
        "encoder_checkpoint_sha256": feats.attrs.get("checkpoint_sha256"),
        "cameras": [frames.attrs["cameras"][c] for c in policy.stores.cameras],
        "tokens_dtype": str(tokens.dtype),
    }
    return TrainingData(tokens, labels, train_frames, val_frames, meta)
