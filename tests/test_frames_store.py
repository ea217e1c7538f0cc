import numpy as np
import pytest
import zarr

from ocpipe.frames import store as FS
from ocpipe.util.atomic import atomic_path


def fake_episode(T, C=2, R=32, seed=0):
    rng = np.random.default_rng(seed)
    return {
        "rgb": rng.integers(0, 255, (T, C, R, R, 3), dtype=np.uint8),
        "seg": rng.integers(0, 20, (T, C, R, R), dtype=np.uint16),
        "qpos": rng.normal(size=(T, 9)).astype(np.float32),
        "action": rng.normal(size=(T, 8)).astype(np.float32),
        "goal_pos": rng.normal(size=(T, 3)).astype(np.float32),
        "tcp_pos": rng.normal(size=(T, 3)).astype(np.float32),
        "obj_pos": rng.normal(size=(T, 3)).astype(np.float32),
        "obj_quat": rng.normal(size=(T, 4)).astype(np.float32),
        "is_grasped": rng.random(T) > 0.5,
        "goal2d_exact": rng.random((T, 2 * C)).astype(np.float32),
        "goal2d_approx": rng.random((T, 2 * C)).astype(np.float32),
        "cam_intrinsic": np.tile(np.eye(3, dtype=np.float32), (T, C, 1, 1)),
        "cam_extrinsic": np.tile(np.eye(3, 4, dtype=np.float32), (T, C, 1, 1)),
    }


def write_shard(path, lengths, seed0, chunk=7):
    w = FS.StoreWriter(path, ["base", "side"], 32, chunk)
    eps = [fake_episode(T, seed=seed0 + i) for i, T in enumerate(lengths)]
    for i, ep in enumerate(eps):
        w.add(ep, i)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).tolist()
    w.close({"task": "PickCube-v1", "camera_set": "dual", "cameras": ["base", "side"], "resolution": 32,
             "episode_seeds": [seed0 + i for i in range(len(lengths))], "episode_ids": list(range(len(lengths))),
             "episode_offsets": offsets, "replay_success_rate": 1.0})
    return eps


def test_shards_merge_into_a_store_that_meets_the_contract(tmp_path):
    a = write_shard(tmp_path / "a.zarr", [5, 9], 0)
    b = write_shard(tmp_path / "b.zarr", [4], 10)
    attrs = FS.merge([tmp_path / "a.zarr", tmp_path / "b.zarr"], tmp_path / "m.zarr", chunk_frames=6)
    assert FS.check_contract(tmp_path / "m.zarr") == []
    root = FS.open_store(tmp_path / "m.zarr")
    assert attrs["episode_offsets"] == [0, 5, 14, 18] and attrs["episode_seeds"] == [0, 1, 10]
    np.testing.assert_array_equal(root["rgb"][...], np.concatenate([e["rgb"] for e in a + b]))  # exact: uint8 copy
    np.testing.assert_array_equal(root["episode_index"][...], np.repeat([0, 1, 2], [5, 9, 4]))  # exact: integers
    assert root["rgb"].chunks[0] <= 6 and root["cam_extrinsic"].shape == (2, 3, 4)
    assert not list(tmp_path.glob(".tmp-*"))


def test_contract_violations_are_reported(tmp_path):
    write_shard(tmp_path / "a.zarr", [5, 9], 0)
    root = zarr.open_group(str(tmp_path / "a.zarr"), mode="a")
    root.attrs["episode_offsets"] = [0, 5, 13]
    root.attrs["replay_success_rate"] = 0.5
    problems = FS.check_contract(tmp_path / "a.zarr")
    assert any("do not partition 14 frames" in p for p in problems)
    assert any("replay_success_rate is 0.5" in p for p in problems)


def test_a_failed_write_leaves_no_store(tmp_path):
    target = tmp_path / "s.zarr"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            write_shard(tmp, [3], 0)
            raise RuntimeError("killed")
    assert not target.exists() and not list(tmp_path.iterdir())


def test_open_store_names_the_missing_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.zarr"):
        FS.open_store(tmp_path / "nothing.zarr")
