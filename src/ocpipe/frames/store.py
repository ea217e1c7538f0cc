"""The frames store: one Zarr v3 group per (task, camera set, resolution). Its contract: docs/pipeline.md."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import zarr

from ..util.atomic import atomic_path

warnings.filterwarnings("ignore", message=".*numcodecs.*", category=UserWarning)

# name -> (per-frame shape given C cameras and resolution R, dtype)
PER_FRAME = {
    "rgb": (lambda C, R: (C, R, R, 3), "uint8"),
    "seg": (lambda C, R: (C, R, R), "uint16"),
    "qpos": (lambda C, R: (9,), "float32"),
    "action": (lambda C, R: (8,), "float32"),
    "goal_pos": (lambda C, R: (3,), "float32"),
    "tcp_pos": (lambda C, R: (3,), "float32"),
    "obj_pos": (lambda C, R: (3,), "float32"),
    "obj_quat": (lambda C, R: (4,), "float32"),
    "is_grasped": (lambda C, R: (), "bool"),
    "episode_index": (lambda C, R: (), "int64"),
    "goal2d_exact": (lambda C, R: (2 * C,), "float32"),
    "goal2d_approx": (lambda C, R: (2 * C,), "float32"),
}
RGB_CHUNK_BYTES = 64 * 2**20  # keep one rgb chunk (the unit read into RAM) around 64 MiB


def _chunk_len(name: str, C: int, R: int, chunk_frames: int) -> int:
    if name not in ("rgb", "seg"):
        return chunk_frames
    return max(1, min(chunk_frames, RGB_CHUNK_BYTES // (C * R * R * 3)))


class StoreWriter:
    """Appends episodes to a new store, writing whole chunks at a time."""

    def __init__(self, path: str | Path, cameras: list[str], resolution: int, chunk_frames: int,
                 moving_cameras: bool = False):
        self.C, self.R = len(cameras), resolution
        self.root = zarr.open_group(str(path), mode="w", zarr_format=3)
        self.arrays = {}
        for name, (shape_fn, dtype) in PER_FRAME.items():
            shape = shape_fn(self.C, self.R)
            self.arrays[name] = self.root.create_array(
                name, shape=(0, *shape), dtype=dtype, chunks=(_chunk_len(name, self.C, self.R, chunk_frames), *shape))
        if moving_cameras:  # the hand camera moves: its matrices change every frame
            for name, shape in (
                ("cam_intrinsic_per_frame", (self.C, 3, 3)),
                ("cam_extrinsic_per_frame", (self.C, 3, 4)),
            ):
                self.arrays[name] = self.root.create_array(
                    name, shape=(0, *shape), dtype="float32", chunks=(chunk_frames, *shape)
                )
        self.buffers = {name: [] for name in self.arrays}
        self.buffered = 0
        self.chunk_frames = chunk_frames
        self.camera_matrices: tuple[np.ndarray, np.ndarray] | None = None

    def add(self, arrays: dict[str, np.ndarray], episode_index: int) -> None:
        n = len(arrays["action"])
        arrays = dict(arrays, episode_index=np.full(n, episode_index, dtype=np.int64))
        if self.camera_matrices is None:
            self.camera_matrices = (arrays["cam_intrinsic"][0], arrays["cam_extrinsic"][0])
        if "cam_extrinsic_per_frame" in self.arrays:
            arrays["cam_intrinsic_per_frame"] = arrays["cam_intrinsic"]
            arrays["cam_extrinsic_per_frame"] = arrays["cam_extrinsic"]
        for name in self.arrays:
            self.buffers[name].append(arrays[name])
        self.buffered += n
        if self.buffered >= self.chunk_frames:
            self.flush()

    def flush(self) -> None:
        if not self.buffered:
            return
        for name, arr in self.arrays.items():
            arr.append(np.concatenate(self.buffers[name]).astype(arr.dtype, copy=False), axis=0)
            self.buffers[name] = []
        self.buffered = 0

    def close(self, attrs: dict) -> None:
        self.flush()
        K, E = (
            self.camera_matrices
            if self.camera_matrices is not None
            else (np.zeros((self.C, 3, 3)), np.zeros((self.C, 3, 4)))
        )
        self.root.create_array("cam_intrinsic", shape=(self.C, 3, 3), dtype="float64")[...] = K
        self.root.create_array("cam_extrinsic", shape=(self.C, 3, 4), dtype="float64")[...] = E
        self.root.attrs.update(attrs)


CAMERA_MATRICES = {"cam_intrinsic": (3, 3), "cam_extrinsic": (3, 4)}


def open_store(path: str | Path, need: tuple[str, ...] = ()) -> zarr.Group:
    """Open the frames store at ``path`` read-only. ``need``: arrays the caller reads; each must exist, hold one
    row per frame (episode_offsets[-1]) and have its contract shape, else a ValueError names the store and array."""
    path = Path(path)
    if not (path / "zarr.json").is_file():
        raise FileNotFoundError(f"no Zarr store at {path}")
    root = zarr.open_group(str(path), mode="r", zarr_format=3)
    problems = _array_problems(root, need) if need else []
    if problems:
        raise ValueError(
            f"{path}: frames store is damaged: {'; '.join(problems)}; delete it and rerun the workflow to rebuild it"
        )
    return root


def _array_problems(root: zarr.Group, need: tuple[str, ...]) -> list[str]:
    attrs = root.attrs.asdict()
    if "episode_offsets" not in attrs:
        return ["attr 'episode_offsets' missing"]
    N = attrs["episode_offsets"][-1]
    C = len(attrs["cameras"]) if "cameras" in attrs else None
    R = attrs.get("resolution")
    problems = []
    for name in need:
        if name not in root:
            problems.append(f"array {name!r} missing")
            continue
        shape = root[name].shape
        if name in CAMERA_MATRICES:
            want = (C, *CAMERA_MATRICES[name])
        elif name in PER_FRAME:
            want = (N, *PER_FRAME[name][0](C, R)) if name not in ("goal2d_exact", "goal2d_approx") or C else None
        else:
            want = None
        if want is None:
            continue
        if name not in CAMERA_MATRICES and shape[:1] != (N,):
            problems.append(f"{name} has {shape[0] if shape else 0} frames, episode_offsets end at {N}")
        elif len(shape) != len(want) or any(w is not None and s != w for s, w in zip(shape, want)):
            problems.append(f"{name} has shape {shape}, expected {want}")
    return problems


def merge(shard_paths: list[str | Path], out_path: str | Path, chunk_frames: int) -> dict:
    """Concatenate shard stores (in order) into one store, atomically. Returns the merged attrs."""
    shards = [open_store(p, need=(*PER_FRAME, *CAMERA_MATRICES)) for p in shard_paths]
    first = shards[0].attrs.asdict()
    cameras, R = first["cameras"], first["resolution"]
    for p, s in zip(shard_paths, shards):
        a = s.attrs.asdict()
        if (a["task"], a["cameras"], a["resolution"]) != (first["task"], cameras, R):
            raise ValueError(f"{p}: shard of a different store ({a['task']}, {a['cameras']}, {a['resolution']})")
    seeds, ids, offsets = [], [], [0]
    for s in shards:
        a = s.attrs.asdict()
        seeds += a["episode_seeds"]
        ids += a["episode_ids"]
        offsets += [offsets[-1] + o for o in a["episode_offsets"][1:]]
    with atomic_path(out_path) as tmp:
        writer = StoreWriter(tmp, cameras, R, chunk_frames, moving_cameras="cam_extrinsic_per_frame" in shards[0])
        ep_base = 0
        for s in shards:
            a = s.attrs.asdict()
            for e in range(len(a["episode_seeds"])):
                lo, hi = a["episode_offsets"][e], a["episode_offsets"][e + 1]
                block = {name: s[name][lo:hi] for name in writer.arrays if name in s}
                block["cam_intrinsic"] = np.broadcast_to(s["cam_intrinsic"][...], (hi - lo, *s["cam_intrinsic"].shape))
                block["cam_extrinsic"] = np.broadcast_to(s["cam_extrinsic"][...], (hi - lo, *s["cam_extrinsic"].shape))
                if "cam_extrinsic_per_frame" in s:
                    block["cam_intrinsic"], block["cam_extrinsic"] = (
                        block["cam_intrinsic_per_frame"],
                        block["cam_extrinsic_per_frame"],
                    )
                writer.add(block, ep_base + e)
            ep_base += len(a["episode_seeds"])
        attrs = dict(
            first,
            episode_seeds=seeds,
            episode_ids=ids,
            episode_offsets=offsets,
            replay_success_rate=float(np.mean([s.attrs["replay_success_rate"] for s in shards])),
            shards=len(shards),
        )
        writer.close(attrs)
    return attrs


def check_contract(path: str | Path) -> list[str]:
    """Every way the store at ``path`` breaks the contract in docs/pipeline.md (empty list: it meets it)."""
    root = open_store(path)
    problems = []
    attrs = root.attrs.asdict()
    for key in ("task", "cameras", "resolution", "episode_seeds", "episode_offsets", "replay_success_rate"):
        if key not in attrs:
            problems.append(f"attr {key!r} missing")
    if problems:
        return problems
    C, R = len(attrs["cameras"]), attrs["resolution"]
    N = root["action"].shape[0] if "action" in root else 0
    for name, (shape_fn, dtype) in PER_FRAME.items():
        if name not in root:
            problems.append(f"array {name!r} missing")
            continue
        want = (N, *shape_fn(C, R))
        if root[name].shape != want or root[name].dtype != np.dtype(dtype):
            problems.append(f"{name}: {root[name].shape} {root[name].dtype}, expected {want} {dtype}")
    for name, shape in (("cam_intrinsic", (C, 3, 3)), ("cam_extrinsic", (C, 3, 4))):
        if name not in root or root[name].shape != shape:
            problems.append(f"{name}: expected shape {shape}")
    offsets = attrs["episode_offsets"]
    if len(offsets) != len(attrs["episode_seeds"]) + 1 or offsets[0] != 0 or offsets[-1] != N:
        problems.append(
            f"episode_offsets {offsets[:3]}...{offsets[-1:]} do not partition {N} frames "
            f"into {len(attrs['episode_seeds'])} episodes"
        )
    elif N:
        ep_index = root["episode_index"][...]
        expect = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
        if not np.array_equal(ep_index, expect):
            problems.append("episode_index disagrees with episode_offsets")
    if attrs["replay_success_rate"] != 1.0:
        problems.append(f"replay_success_rate is {attrs['replay_success_rate']}, not 1.0")
    return problems
