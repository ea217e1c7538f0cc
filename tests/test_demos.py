import json

import h5py
import numpy as np
import pytest
from fake_demos import write

from ocpipe.demos.files import DemoError, episodes
from ocpipe.demos.merge import import_official, merge
from ocpipe.demos.motion_planning import shard_seed_range
from ocpipe.frames import replay

LEX_ORDER = sorted(range(12), key=lambda i: f"traj_{i}")  # 0, 1, 10, 11, 2, ...


def test_episodes_are_ordered_numerically_and_keep_their_seeds(tmp_path):
    seeds = [100 + 7 * i for i in range(12)]
    path_json = write(tmp_path / "d.h5", seeds, json_order=LEX_ORDER)
    eps = episodes(path_json)
    assert [e["episode_id"] for e in eps] == list(range(12))
    assert [e["episode_seed"] for e in eps] == seeds


def test_replay_shards_are_contiguous_numeric_blocks(tmp_path):
    path_json = write(tmp_path / "d.h5", list(range(12)), json_order=LEX_ORDER)
    blocks = [replay.select_episodes(path_json, s, 5) for s in range(5)]
    ids = [e["episode_id"] for b in blocks for e in b]
    assert ids == list(range(12)) and all(blocks)


def test_missing_seed_is_an_error(tmp_path):
    path_json = write(tmp_path / "d.h5", [0, 1])
    meta = json.loads(open(path_json).read())
    del meta["episodes"][1]["episode_seed"]
    open(path_json, "w").write(json.dumps(meta))
    with pytest.raises(DemoError, match="episode 1 has no episode_seed"):
        episodes(path_json)


def test_shard_seed_ranges_are_disjoint_and_cover_the_demos(default_config):
    cfg = dict(default_config, demos=dict(default_config["demos"], num_demos=10, shards=3, attempts_per_demo=2))
    ranges = [shard_seed_range(cfg, s) for s in range(3)]
    assert sum(n for _, n in ranges) == 10
    seeds = [s for r, _ in ranges for s in r]
    assert len(seeds) == len(set(seeds)) == 20 and min(seeds) == 0
    with pytest.raises(DemoError, match="shard 3 out of range"):
        shard_seed_range(cfg, 3)


def test_import_renumbers_in_numeric_order_and_truncates(tmp_path, default_config):
    seeds = [500 + i for i in range(12)]
    path_json = write(tmp_path / "official.h5", seeds, json_order=LEX_ORDER)
    cfg = dict(default_config, demos=dict(default_config["demos"], num_demos=11))
    out = tmp_path / "out" / "PickCube-v1.h5"
    import_official(tmp_path / "official.h5", path_json, out, cfg, "PickCube-v1")
    eps = episodes(out.with_suffix(".json"))
    assert [e["episode_seed"] for e in eps] == seeds[:11]
    with h5py.File(out) as f:
        assert sorted(f.keys(), key=lambda k: int(k.split("_")[1])) == [f"traj_{i}" for i in range(11)]
        for e in eps:  # each renumbered trajectory still holds the data of the same source episode
            assert f[f"traj_{e['episode_id']}/actions"][0, 0] == e["episode_seed"] - 500


def test_import_converts_relative_joint_control_to_absolute_targets(tmp_path, default_config):
    path_json = write(tmp_path / "official.h5", [3, 4], control_mode="pd_joint_delta_pos")
    out = tmp_path / "PickCube-v1.h5"
    import_official(tmp_path / "official.h5", path_json, out, default_config, "PickCube-v1")
    with h5py.File(out) as f:
        a = f["traj_0/actions"][()]
    # absolute target of step t = arm joints of recorded state t+1 (qpos[j] = j + t + 1); gripper kept
    # exact: the import copies float32 whole numbers out of the recorded states and actions, no arithmetic
    np.testing.assert_array_equal(a[:, :7], np.arange(7)[None] + np.arange(1, len(a) + 1)[:, None])
    np.testing.assert_array_equal(a[:, 7], -1)  # exact: the gripper command copied as recorded
    assert all(e["control_mode"] == "pd_joint_pos" for e in episodes(out.with_suffix(".json")))


def test_import_rejects_held_out_seeds_wrong_task_and_missing_files(tmp_path, default_config):
    path_json = write(tmp_path / "a.h5", [1, 10_005])
    with pytest.raises(DemoError, match="10005.*held-out pool"):
        import_official(tmp_path / "a.h5", path_json, tmp_path / "o.h5", default_config, "PickCube-v1")
    path_json = write(tmp_path / "b.h5", [1], env_id="StackCube-v1")
    with pytest.raises(DemoError, match="env_id is 'StackCube-v1'"):
        import_official(tmp_path / "b.h5", path_json, tmp_path / "o.h5", default_config, "PickCube-v1")
    with pytest.raises(DemoError, match="demos.import.PickCube-v1.h5: file not found"):
        import_official(tmp_path / "nope.h5", path_json, tmp_path / "o.h5", default_config, "PickCube-v1")
    assert not (tmp_path / "o.h5").exists() and not list(tmp_path.glob(".tmp-*"))


def test_merge_refuses_duplicate_seeds(tmp_path):
    a = tmp_path / "a.h5"
    b = tmp_path / "b.h5"
    write(a, [1, 2])
    write(b, [2, 3])
    with pytest.raises(DemoError, match=r"duplicate episode seeds.*\[2\]"):
        merge([a, b], tmp_path / "m.h5")


def test_merge_concatenates_shards_with_fresh_ids(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write(a, [0, 1])
    write(b, [4, 5, 6])
    report = merge([a, b], tmp_path / "m.h5", report_path=tmp_path / "m.report.json")
    eps = episodes(tmp_path / "m.json")
    assert [e["episode_id"] for e in eps] == [0, 1, 2, 3, 4]
    assert [e["episode_seed"] for e in eps] == [0, 1, 4, 5, 6]
    # exact: integer counts and seeds
    assert report["episodes"] == 5 and json.loads((tmp_path / "m.report.json").read_text())["seed_max"] == 6
