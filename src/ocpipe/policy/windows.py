"""Training samples built by index from per-frame stores, and the chunk-aware epoch iterator.

A sample for frame i of an episode [s, e): the visual tokens and labels of frames i-T+1 .. i (the first frame
repeated before s) and the actions of frames i .. i+H-1 (the last action repeated from e on), with each target
action's episode progress p = (j - s) / (e - 1 - s).

Only the visual tokens are large (thesis: 4.5 GB of windows); labels fit in RAM. Each epoch visits the feature
store's chunks in a shuffled order, reads one chunk (plus the T-1 frames before it) at a time, and yields its
windows in shuffled order, so at most one chunk is held in memory and every window comes exactly once."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class Labels:
    """Per-frame raw inputs and targets in RAM (policy.observation; the model's Normalizer standardizes them) and
    the episode bounds of every frame."""

    proprio: np.ndarray  # (N, P)
    goal: np.ndarray  # (N, G), G = 0 for no goal
    action: np.ndarray  # (N, 8): the expert's absolute joint targets and gripper command
    start: np.ndarray  # (N,) first frame of the frame's episode
    end: np.ndarray  # (N,) one past its last frame
    qpos: np.ndarray | None = None  # (N, 9) the robot's joints: what residual targets are relative to
    aux: np.ndarray | None = None  # (N, 3) the object's position, the auxiliary head's target
    readout: np.ndarray | None = None  # (N, 5) the object's pose, the object read-out's target

    @classmethod
    def from_offsets(cls, offsets, proprio, goal, action, **extra) -> "Labels":
        offsets = np.asarray(offsets, dtype=np.int64)
        lengths = np.diff(offsets)
        if (lengths <= 0).any():
            raise ValueError(
                f"episode {int(np.argmax(lengths <= 0))} has no frames (episode_offsets {offsets.tolist()})"
            )
        return cls(proprio, goal, action, np.repeat(offsets[:-1], lengths), np.repeat(offsets[1:], lengths), **extra)


def window_frames(frames: np.ndarray, labels: Labels, T: int) -> np.ndarray:
    """(n,) current frames -> (n, T) frame ids, oldest first, clamped to the episode start."""
    idx = frames[:, None] - np.arange(T - 1, -1, -1)[None]
    return np.maximum(idx, labels.start[frames][:, None])


def action_frames(frames: np.ndarray, labels: Labels, H: int) -> np.ndarray:
    """(n,) current frames -> (n, H) frame ids of the target actions, clamped to the episode's last frame."""
    return np.minimum(frames[:, None] + np.arange(H)[None], labels.end[frames][:, None] - 1)


def progress(target_frames: np.ndarray, frames: np.ndarray, labels: Labels) -> np.ndarray:
    s, e = labels.start[frames][:, None], labels.end[frames][:, None]
    return ((target_frames - s) / np.maximum(e - 1 - s, 1)).astype(np.float32)


def make_batch(
    tokens: np.ndarray, base: int, frames: np.ndarray, labels: Labels, T: int, H: int, cameras: list[int]
) -> dict[str, torch.Tensor]:
    """Assemble samples for ``frames``; ``tokens`` holds store frames base .. base+len(tokens)."""
    win = window_frames(frames, labels, T)
    act = action_frames(frames, labels, H)
    batch = {
        "tokens": torch.from_numpy(np.ascontiguousarray(tokens[win - base][:, :, cameras], dtype=np.float32)),
        "proprio": torch.from_numpy(labels.proprio[win]),
        "goal": torch.from_numpy(labels.goal[win]),
        "action": torch.from_numpy(labels.action[act]),
        "progress": torch.from_numpy(progress(act, frames, labels)),
        "frame": torch.from_numpy(frames),
    }
    if labels.qpos is not None:
        batch["qpos"] = torch.from_numpy(labels.qpos[frames])
    if labels.aux is not None:
        batch["aux"] = torch.from_numpy(labels.aux[frames])
    if labels.readout is not None:
        batch["readout"] = torch.from_numpy(labels.readout[win])
    return batch


class ChunkWindowLoader:
    """Epoch iterator over windows, one feature-store chunk in RAM at a time.

    ``tokens`` is a Zarr array (or anything sliceable) of shape (N, C, K, D); ``frames`` the current-frame ids
    to train on (default: all). Batches do not straddle chunks, so a chunk's last batch may be smaller."""

    def __init__(
        self,
        tokens,
        labels: Labels,
        T: int,
        H: int,
        batch_size: int,
        cameras: list[int],
        seed: int,
        frames: np.ndarray | None = None,
        chunk_frames: int | None = None,
    ):
        self.tokens, self.labels, self.T, self.H = tokens, labels, T, H
        self.batch_size, self.cameras, self.seed = batch_size, list(cameras), seed
        n = tokens.shape[0]
        self.frames = np.arange(n) if frames is None else np.sort(np.asarray(frames))
        self.chunk_frames = chunk_frames or getattr(tokens, "chunks", (n,))[0]
        bounds = np.arange(0, n + self.chunk_frames, self.chunk_frames)
        self.chunks = [(lo, min(hi, n)) for lo, hi in zip(bounds[:-1], bounds[1:]) if lo < n]
        self.chunks_in_ram = 0
        self.max_chunks_in_ram = 0

    def __len__(self) -> int:
        return sum(-(-len(self._frames_in(lo, hi)) // self.batch_size) for lo, hi in self.chunks)

    def _frames_in(self, lo: int, hi: int) -> np.ndarray:
        return self.frames[np.searchsorted(self.frames, lo) : np.searchsorted(self.frames, hi)]

    def epoch(self, epoch: int):
        rng = np.random.default_rng([self.seed, epoch])
        for c in rng.permutation(len(self.chunks)):
            lo, hi = self.chunks[c]
            frames = self._frames_in(lo, hi)
            if not len(frames):
                continue
            base = max(0, lo - (self.T - 1))
            block = np.asarray(self.tokens[base:hi])
            self.chunks_in_ram += 1
            self.max_chunks_in_ram = max(self.max_chunks_in_ram, self.chunks_in_ram)
            try:
                order = rng.permutation(frames)
                for b in range(0, len(order), self.batch_size):
                    yield make_batch(
                        block, base, order[b : b + self.batch_size], self.labels, self.T, self.H, self.cameras
                    )
            finally:
                del block
                self.chunks_in_ram -= 1
