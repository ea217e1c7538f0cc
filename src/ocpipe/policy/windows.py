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
    tokens: np.ndarray, base: int, frames: np.ndarray, labels: Labels, T: int, H: int, cameras: list[int],
    covered_from: np.ndarray | None = None,
) -> dict[str, torch.Tensor]:
    """Assemble samples for ``frames``; ``tokens`` holds store frames base .. base+len(tokens).

    With ``covered_from`` (n,) the batch supervises every step of each window (action loss `every_step`): the
    targets, their progress and the joints they are relative to come per step, (n, T, ...), and ``step_mask``
    (n, T) keeps a step only if it is its frame's first place in the window (not a repeat of the episode's first
    frame) and at or after ``covered_from``, so each frame of an epoch's windows is supervised once."""
    win = window_frames(frames, labels, T)
    target_frames = frames if covered_from is None else win
    act = action_frames(target_frames.reshape(-1), labels, H).reshape(*target_frames.shape, H)
    batch = {
        "tokens": torch.from_numpy(np.ascontiguousarray(tokens[win - base][:, :, cameras], dtype=np.float32)),
        "proprio": torch.from_numpy(labels.proprio[win]),
        "goal": torch.from_numpy(labels.goal[win]),
        "action": torch.from_numpy(labels.action[act]),
        "progress": torch.from_numpy(progress(act.reshape(len(act), -1), frames, labels).reshape(act.shape)),
        "frame": torch.from_numpy(frames),
    }
    if covered_from is not None:
        first_place = np.ones_like(win, dtype=bool)
        first_place[:, 1:] = win[:, 1:] != win[:, :-1]
        batch["step_mask"] = torch.from_numpy(first_place & (win >= covered_from[:, None]))
    if labels.qpos is not None:
        batch["qpos"] = torch.from_numpy(labels.qpos[target_frames])
    if labels.aux is not None:
        batch["aux"] = torch.from_numpy(labels.aux[frames])
    if labels.readout is not None:
        batch["readout"] = torch.from_numpy(labels.readout[win])
    return batch


class ChunkWindowLoader:
    """Epoch iterator over windows, one feature-store chunk in RAM at a time.

    ``tokens`` is a Zarr array (or anything sliceable) of shape (N, C, K, D); ``frames`` the current-frame ids
    to train on (default: all). Batches do not straddle chunks, so a chunk's last batch may be smaller.

    ``every_step``: each window supervises all its steps (make_batch's ``covered_from``), so an epoch needs only
    the windows ending every T frames of an episode, and at its last frame: about 1/T of them. The grid's phase is
    drawn per epoch, so a frame is not always at the same place in its window; it is drawn apart from the shuffling,
    so an epoch's batch count is known before it runs (the learning-rate schedule counts them)."""

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
        every_step: bool = False,
    ):
        self.tokens, self.labels, self.T, self.H = tokens, labels, T, H
        self.batch_size, self.cameras, self.seed = batch_size, list(cameras), seed
        self.every_step = every_step
        n = tokens.shape[0]
        self.frames = np.arange(n) if frames is None else np.sort(np.asarray(frames))
        self.chunk_frames = chunk_frames or getattr(tokens, "chunks", (n,))[0]
        bounds = np.arange(0, n + self.chunk_frames, self.chunk_frames)
        self.chunks = [(lo, min(hi, n)) for lo, hi in zip(bounds[:-1], bounds[1:]) if lo < n]
        self.chunks_in_ram = 0
        self.max_chunks_in_ram = 0

    def __len__(self) -> int:
        return self.batches(0)

    def batches(self, epoch: int) -> int:
        """The number of batches epoch ``epoch`` (0-based) yields."""
        frames, _ = self._epoch_frames(epoch)
        return sum(-(-(inside.stop - inside.start) // self.batch_size) for _, inside in self._in_chunks(frames))

    def _in_chunks(self, frames: np.ndarray) -> list[tuple[tuple[int, int], slice]]:
        """Each chunk's bounds and the slice of the sorted ``frames`` that falls in it."""
        return [((lo, hi), slice(int(np.searchsorted(frames, lo)), int(np.searchsorted(frames, hi))))
                for lo, hi in self.chunks]

    def _epoch_frames(self, epoch: int) -> tuple[np.ndarray, np.ndarray | None]:
        """-> (the current frames of the epoch's windows, sorted; with every_step, the first frame each window
        supervises: one past the episode's previous window, or the episode's start)."""
        if not self.every_step:
            return self.frames, None
        phase = int(np.random.default_rng([self.seed, epoch, self.T]).integers(self.T))
        f, start, end = self.frames, self.labels.start[self.frames], self.labels.end[self.frames]
        chosen = f[((f - start + phase) % self.T == self.T - 1) | (f == end - 1)]
        first = self.labels.start[chosen].copy()
        same_episode = first[1:] == first[:-1]
        first[1:][same_episode] = chosen[:-1][same_episode] + 1
        return chosen, first

    def epoch(self, epoch: int):
        rng = np.random.default_rng([self.seed, epoch])
        epoch_frames, covered_from = self._epoch_frames(epoch)
        in_chunks = self._in_chunks(epoch_frames)
        for c in rng.permutation(len(self.chunks)):
            (lo, hi), inside = in_chunks[c]
            frames = epoch_frames[inside]
            if not len(frames):
                continue
            base = max(0, lo - (self.T - 1))
            block = np.asarray(self.tokens[base:hi])
            self.chunks_in_ram += 1
            self.max_chunks_in_ram = max(self.max_chunks_in_ram, self.chunks_in_ram)
            try:
                order = rng.permutation(len(frames))
                for b in range(0, len(order), self.batch_size):
                    pick = order[b : b + self.batch_size]
                    yield make_batch(block, base, frames[pick], self.labels, self.T, self.H, self.cameras,
                                     None if covered_from is None else covered_from[inside][pick])
            finally:
                del block
                self.chunks_in_ram -= 1
