"""Small synthetic frames + features stores in the real layouts, for policy tests and benchmarks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ocpipe.sim import projection

# two fixed cameras looking at the workspace, for the stores' exact 2d goal
CAMERAS = {"base": {"eye": [0.3, 0.0, 0.6], "target": [-0.1, 0.0, 0.1], "fov_deg": 60.0},
           "side": {"eye": [0.0, 0.5, 0.4], "target": [0.0, 0.0, 0.1], "fov_deg": 60.0}}
RESOLUTION = 64


def camera_matrices(names) -> tuple[np.ndarray, np.ndarray]:
    K = np.stack([projection.intrinsic_from_fov(RESOLUTION, CAMERAS[c]["fov_deg"]) for c in names])
    E = np.stack([projection.extrinsic_look_at(CAMERAS[c]["eye"], CAMERAS[c]["target"]) for c in names])
    return K.astype(np.float32), E.astype(np.float32)


def _put(group, name, data, chunks=None):
    arr = group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=chunks or data.shape)
    arr[...] = data


def write_stores(root: Path, lengths=(30, 25, 40), C=2, K=7, D=16, chunk=32, seed=0) -> tuple[Path, Path]:
    import zarr  # here, so policy_settings needs only numpy (bench/check_cuda.py runs where zarr is not)

    rng = np.random.default_rng(seed)
    N = sum(lengths)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).tolist()
    frames = zarr.open_group(str(root / "frames.zarr"), mode="w", zarr_format=3)
    qpos = np.concatenate([rng.normal(0, 0.5, (N, 7)), rng.uniform(0.018, 0.04, (N, 1)).repeat(2, 1)], 1)
    action = np.concatenate([rng.normal(0, 0.5, (N, 7)), rng.choice([-1.0, 1.0], (N, 1))], 1)
    quat = rng.normal(size=(N, 4))
    cameras = ["base", "side"][:C]
    K_, E_ = camera_matrices(cameras)
    goal = rng.uniform(-0.1, 0.3, (N, 3)).astype(np.float32)
    for name, arr in {
        "qpos": qpos,
        "action": action,
        "goal_pos": goal,
        "obj_pos": rng.uniform(-0.1, 0.1, (N, 3)),
        "obj_quat": quat / np.linalg.norm(quat, axis=1)[:, None],
        "goal2d_exact": projection.goal2d(goal, K_, E_, RESOLUTION),
        "tcp_pos": np.random.default_rng(seed + 1).uniform(-0.1, 0.3, (N, 3)),  # own stream: other arrays unchanged
        "cam_intrinsic": K_,
        "cam_extrinsic": E_,
    }.items():
        _put(frames, name, arr.astype(np.float32))
    frames.attrs.update({"episode_offsets": offsets, "cameras": cameras, "task": "PickCube-v1",
                         "resolution": RESOLUTION})
    feats = zarr.open_group(str(root / "features.zarr"), mode="w", zarr_format=3)
    _put(feats, "tokens", rng.normal(0, 1, (N, C, K, D)).astype(np.float16), chunks=(chunk, C, K, D))
    feats.attrs.update({"encoder": "synthetic", "checkpoint_sha256": None})
    return root / "features.zarr", root / "frames.zarr"


def policy_settings(**overrides) -> dict:
    base = dict(
        task="PickCube-v1",
        cams="dual",
        resolution=64,
        encoder="slots_ssl",
        cameras=[0, 1],
        goal="2d",
        goal_calibration="exact",
        proprio="joints7",
        window=3,
        horizon=4,
        width=32,
        layers=2,
        heads=4,
        dropout=0.1,
        fusion="concat",
        visual_head="tokens",
        action_head="linear",
        gripper="regression",
        loss_weighting="uniform",
        time_weight_warmup_epochs=0,
        epochs=4,
        save_every=2,
        batch_size=16,
        lr=1e-3,
        weight_decay=0.01,
        grad_clip=1.0,
        device="cpu",
        token_norm="none",
        aux_object_weight=0.0,
        joint_targets="absolute",
        object_readout=False,
        val_episodes=0,
        name="test",
    )
    return {**base, **overrides}
