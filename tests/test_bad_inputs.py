"""Every bad input stops its job with an error that names the file, key or episode and says what to do, and
leaves nothing half-written behind (docs/failure-modes.md)."""

import copy
import errno
import json
import shutil

import h5py
import numpy as np
import pytest
import zarr
from fake_demos import write
from policy_stores import policy_settings, write_stores
from test_frames_store import write_shard

from ocpipe.config import validate as C
from ocpipe.demos.files import DemoError, check_pair, episodes
from ocpipe.demos.merge import import_official, merge
from ocpipe.encoders.state import StateEncoder
from ocpipe.evaluation import closed_loop
from ocpipe.features import encode
from ocpipe.frames import render, replay
from ocpipe.frames import store as frames_store
from ocpipe.policy.data import load as load_data


def no_leftovers(folder):
    return not list(folder.glob(".tmp-*")) and not list(folder.glob("*.work"))


# 1. a truncated or corrupt demo .h5 ----------------------------------------------------------------------------


def truncate(path):
    size = path.stat().st_size
    with open(path, "r+b") as fh:
        fh.truncate(size // 2)


def scribble(path):
    """Overwrite the middle third of the file with garbage: the file still opens, some trajectories do not."""
    size = path.stat().st_size
    with open(path, "r+b") as fh:
        fh.seek(size // 3)
        fh.write(np.random.default_rng(0).bytes(size // 3))


def test_truncated_demo_file_is_named_before_anything_runs(tmp_path, default_config):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write(a, [0, 1, 2])
    write(b, [5, 6])
    truncate(a)
    with pytest.raises(DemoError, match=rf"{a}: not a readable HDF5 file.*truncated or corrupt.*delete"):
        check_pair(a)
    with pytest.raises(DemoError, match=rf"{a}: not a readable HDF5 file"):
        merge([a, b], tmp_path / "m.h5")
    assert not (tmp_path / "m.h5").exists() and not (tmp_path / "m.json").exists() and no_leftovers(tmp_path)
    # the frames stage checks the demo file before it builds a simulator
    with pytest.raises(DemoError, match=rf"{a}: not a readable HDF5 file"):
        render.render_shard("PickCube-v1", "dual", 64, a, 0, 1, default_config, tmp_path / "s.zarr", progress=False)
    assert not (tmp_path / "s.zarr").exists() and no_leftovers(tmp_path)
    # so does importing an official file
    with pytest.raises(DemoError, match=rf"{a}: not a readable HDF5 file"):
        import_official(a, a.with_suffix(".json"), tmp_path / "i.h5", default_config, "PickCube-v1")
    assert not (tmp_path / "i.h5").exists() and no_leftovers(tmp_path)
    assert b.is_file() and b.with_suffix(".json").is_file()  # inputs are never touched


def test_corrupt_trajectory_is_named_with_its_episode(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write(a, [0, 1, 2, 3])
    write(b, [5, 6])
    scribble(a)
    with pytest.raises(DemoError, match=rf"{a}: episode \d \(traj_\d\) cannot be read.*corrupt.*delete"):
        merge([a, b], tmp_path / "m.h5")
    assert not (tmp_path / "m.h5").exists() and no_leftovers(tmp_path)
    eps = episodes(a.with_suffix(".json"))
    with h5py.File(a, "r") as h5:
        with pytest.raises(DemoError, match=rf"{a}: episode \d \(traj_\d\) cannot be read"):
            for ep in eps:
                replay.read_episode(h5, ep)


def test_unreadable_demo_json_is_named(tmp_path):
    a = tmp_path / "a.h5"
    write(a, [0, 1])
    a.with_suffix(".json").write_text('{"episodes": [{"episode_id": 0,')
    with pytest.raises(DemoError, match=rf"{a.with_suffix('.json')}: not valid JSON"):
        episodes(a.with_suffix(".json"))


# 2. a demos .json that does not match its .h5 -----------------------------------------------------------------


def edit_json(path_h5, fn):
    path = path_h5.with_suffix(".json")
    meta = json.loads(path.read_text())
    fn(meta)
    path.write_text(json.dumps(meta))


@pytest.mark.parametrize("change, words", [
    (lambda m: m["episodes"].pop(), ["json lists 2 episodes", "h5 holds 3", "not in the json: traj_2"]),
    (lambda m: m["episodes"].append(dict(m["episodes"][0], episode_id=7, episode_seed=9)),
     ["json lists 4 episodes", "h5 holds 3", "missing from the h5: traj_7"]),
    (lambda m: m["episodes"][2].update(episode_id=5), ["missing from the h5: traj_5", "not in the json: traj_2"]),
])
def test_json_that_does_not_match_its_h5_is_refused(tmp_path, change, words):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write(a, [0, 1, 2])
    write(b, [5, 6])
    edit_json(a, change)
    for call in (lambda: check_pair(a), lambda: merge([a, b], tmp_path / "m.h5")):
        with pytest.raises(DemoError) as exc:
            call()
        msg = str(exc.value)
        assert msg.startswith(f"{a} does not match {a.with_suffix('.json')}") and "delete a.h5 and a.json" in msg
        for word in words:
            assert word in msg
    assert not (tmp_path / "m.h5").exists() and no_leftovers(tmp_path)


def test_matching_pairs_still_merge(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write(a, [0, 1, 2])
    write(b, [5, 6])
    assert [e["episode_seed"] for e in check_pair(a)] == [0, 1, 2]
    assert merge([a, b], tmp_path / "m.h5")["episodes"] == 5


# 3. a frames store missing an array, or an array of the wrong shape ---------------------------------------------


class TinyEncoder:
    name, checkpoint = "tiny", None

    def encode(self, rgb):
        import torch

        B, Cm = rgb.shape[:2]
        return torch.zeros(B, Cm, 2, 4), None


def replace_array(store, name, data):
    root = zarr.open_group(str(store), mode="a", zarr_format=3)
    del root[name]
    root.create_array(name, shape=data.shape, dtype=data.dtype)[...] = data


def test_frames_store_missing_an_array_is_named(tmp_path):
    store = tmp_path / "f.zarr"
    write_shard(store, [3, 2], 0)
    shutil.rmtree(store / "rgb")
    with pytest.raises(ValueError, match=rf"{store}: frames store is damaged: array 'rgb' missing.*delete it"):
        encode.encode_store(TinyEncoder(), store, tmp_path / "out.zarr", 2, 2, progress=False, device="cpu")
    assert not (tmp_path / "out.zarr").exists() and no_leftovers(tmp_path)


def test_frames_store_array_of_the_wrong_shape_is_named(tmp_path):
    store = tmp_path / "f.zarr"
    write_shard(store, [3, 2], 0)
    replace_array(store, "rgb", np.zeros((5, 2, 32, 32), np.uint8))  # no colour axis
    with pytest.raises(ValueError, match=rf"{store}: frames store is damaged: rgb has shape \(5, 2, 32, 32\), "
                                         r"expected \(5, 2, 32, 32, 3\)"):
        encode.encode_store(TinyEncoder(), store, tmp_path / "out.zarr", 2, 2, progress=False, device="cpu")
    with pytest.raises(ValueError, match=rf"{store}: frames store is damaged: rgb has shape"):
        frames_store.merge([store], tmp_path / "m.zarr", 4)
    assert not (tmp_path / "out.zarr").exists() and not (tmp_path / "m.zarr").exists() and no_leftovers(tmp_path)


def test_training_names_a_damaged_frames_or_features_store(tmp_path):
    feats, store = write_stores(tmp_path)
    policy = policy_settings()
    load_data(policy, feats, store)  # intact stores load
    replace_array(store, "qpos", np.zeros((50, 9), np.float32))
    with pytest.raises(ValueError, match=rf"{store}: frames store is damaged: qpos has 50 frames, "
                                         r"episode_offsets end at 95"):
        load_data(policy, feats, store)
    shutil.rmtree(store / "action")
    with pytest.raises(ValueError, match=r"array 'action' missing"):
        load_data(policy, feats, store)
    feats2, store2 = write_stores(tmp_path / "b")
    shutil.rmtree(feats2 / "tokens")
    with pytest.raises(ValueError, match=rf"{feats2}: features store has no 'tokens' array.*delete it"):
        load_data(policy, feats2, store2)


# 4. a features store built from another frames store ------------------------------------------------------------


def stamp_provenance(feats, store):
    """What the features stage records about the frames store it encoded."""
    fa = zarr.open_group(str(store), mode="r").attrs.asdict()
    g = zarr.open_group(str(feats), mode="a")
    g.attrs.update({"frames_store": str(store),
                    "frames_store_attrs": {k: fa[k] for k in encode.PROVENANCE_KEYS if k in fa}})


def test_features_of_another_frames_store_are_refused(tmp_path):
    feats, store = write_stores(tmp_path / "a")
    stamp_provenance(feats, store)
    policy = policy_settings()
    load_data(policy, feats, store)
    # same number of frames, other episodes: only the provenance tells them apart
    _, other = write_stores(tmp_path / "b", lengths=(40, 25, 30))
    with pytest.raises(ValueError) as exc:
        load_data(policy, feats, other)
    msg = str(exc.value)
    assert msg.startswith(f"{feats} was encoded from {store}, not from {other}") and "episode_offsets" in msg
    assert "delete" in msg and "rebuild" in msg
    g = zarr.open_group(str(other), mode="a")
    g.attrs.update({"task": "StackCube-v1", "episode_offsets": [0, 30, 55, 95]})
    with pytest.raises(ValueError, match=r"task: 'PickCube-v1' there, 'StackCube-v1' here"):
        load_data(policy, feats, other)


# 5. a policy checkpoint from another encoder or another task ----------------------------------------------------


def test_checkpoint_of_another_task_or_encoder_is_refused_before_the_simulator_starts(tmp_path):
    store = tmp_path / "f.zarr"
    write_shard(store, [3], 0)  # PickCube-v1, dual, 32 px
    ckpt = tmp_path / "runs" / "exp" / "checkpoints" / "epoch_0002.pt"
    enc_ckpt = tmp_path / "model.pt"
    enc_ckpt.write_bytes(b"encoder weights")
    policy = policy_settings(resolution=32, name="exp")
    meta = {"encoder": "slots_ssl", "encoder_checkpoint_sha256": encode.sha256(enc_ckpt)}
    closed_loop.check_checkpoint(ckpt, policy, meta, store, enc_ckpt, expected=policy)  # all agree

    other_task = dict(policy, task="StackCube-v1")
    with pytest.raises(ValueError, match=rf"{ckpt}: trained for task 'StackCube-v1'.*{store} is a frames store of "
                                         r"task 'PickCube-v1'"):
        closed_loop.check_checkpoint(ckpt, other_task, meta, store, enc_ckpt)
    with pytest.raises(ValueError, match=rf"{ckpt}: trained for task 'StackCube-v1', but experiment 'exp' has "
                                         r"task 'PickCube-v1'.*retrain"):
        closed_loop.check_checkpoint(ckpt, other_task, meta, tmp_path / "nostore.zarr", enc_ckpt, expected=policy)
    with pytest.raises(ValueError, match=rf"{ckpt}: trained for resolution 64.*resolution 32"):
        closed_loop.check_checkpoint(ckpt, dict(policy, resolution=64), meta, store, enc_ckpt)

    dino = dict(policy, encoder="dino_cls")
    with pytest.raises(ValueError, match=rf"{ckpt}: trained for encoder 'dino_cls', but experiment 'exp' has "
                                         r"encoder 'slots_ssl'"):
        closed_loop.check_checkpoint(ckpt, dino, dict(meta, encoder="dino_cls"), store, None, expected=policy)
    with pytest.raises(ValueError, match=rf"{ckpt}: its policy names encoder 'dino_cls' but it was trained on "
                                         r"'slots_ssl' features"):
        closed_loop.check_checkpoint(ckpt, dino, meta, store, None)
    other_weights = tmp_path / "other.pt"
    other_weights.write_bytes(b"other weights")
    with pytest.raises(ValueError, match=rf"{other_weights} is not the encoder checkpoint that {ckpt} was trained "
                                         r"on \(sha256 differs\)"):
        closed_loop.check_checkpoint(ckpt, policy, meta, store, other_weights)


def test_control_checkpoint_of_another_state_token_layout_is_refused(tmp_path):
    ckpt = tmp_path / "epoch_0016.pt"
    closed_loop.check_state_tokens(ckpt, {"D": 8}, StateEncoder(tcp_relative=True))
    with pytest.raises(ValueError, match=rf"{ckpt}: trained on 5-dim state tokens, but encoders.state.tcp_relative "
                                         r"= True makes 8-dim ones"):
        closed_loop.check_state_tokens(ckpt, {"D": 5}, StateEncoder(tcp_relative=True))


# 6. a config whose experiment names an unknown key --------------------------------------------------------------


def test_unknown_experiment_key_is_named_with_a_suggestion(default_config):
    cfg = copy.deepcopy(default_config)
    name = next(iter(cfg["experiments"]))
    cfg["experiments"][name] = dict(cfg["experiments"][name] or {}, lrr=0.1)
    with pytest.raises(C.ConfigError) as exc:
        C.validate(cfg)
    msg = str(exc.value)
    assert f"experiments.{name}.lrr: unknown key; did you mean 'lr'?" in msg
    assert "allowed keys:" in msg and "'epochs'" in msg
    cfg = copy.deepcopy(default_config)
    cfg["policy"]["windw"] = 3
    with pytest.raises(C.ConfigError, match=r"policy.windw: unknown key; did you mean 'window'\?"):
        C.validate(cfg)


@pytest.mark.parametrize("override,words", [
    ({"task": "PushCube-v1"}, "experiments.goal3d.task: 'PushCube-v1' is not one of"),
    ({"cams": "stereo"}, "experiments.goal3d.cams: 'stereo' is not one of"),
    ({"encoder": "clip"}, "experiments.goal3d.encoder: 'clip' is not one of"),
    ({"cameras": [0, 2]}, "experiments.goal3d.cameras: a frames store has two cameras"),
])
def test_an_experiment_naming_a_store_no_rule_makes_is_refused(default_config, override, words):
    """A task, camera set, encoder or camera no rule can build a store for stops at validation, naming the key."""
    cfg = copy.deepcopy(default_config)
    cfg["experiments"]["goal3d"] = dict(cfg["experiments"]["goal3d"], **override)
    with pytest.raises(C.ConfigError) as exc:
        C.validate(cfg)
    assert words in str(exc.value)


# 7. a full disk while a store is written ------------------------------------------------------------------------


def disk_full_on_call(monkeypatch, owner, attr, n):
    """Make owner.attr raise ENOSPC on its n-th call, as a full disk would in the middle of a write."""
    original, calls = getattr(owner, attr), []

    def fail(*args, **kwargs):
        calls.append(1)
        if len(calls) == n:
            raise OSError(errno.ENOSPC, "No space left on device")
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, attr, fail)
    return calls


def test_full_disk_while_merging_frames_leaves_nothing(tmp_path, monkeypatch):
    shards = [tmp_path / "s0.zarr", tmp_path / "s1.zarr"]
    write_shard(shards[0], [3, 4], 0)
    write_shard(shards[1], [5], 10)
    out = tmp_path / "merged.zarr"
    calls = disk_full_on_call(monkeypatch, frames_store.StoreWriter, "flush", 2)
    with pytest.raises(OSError, match=rf"No space left on device.*{out}.*free space") as exc:
        frames_store.merge(shards, out, chunk_frames=4)
    assert exc.value.errno == errno.ENOSPC and len(calls) == 2  # the first chunk was written, then the disk filled
    assert not out.exists() and no_leftovers(tmp_path)
    assert frames_store.check_contract(shards[0]) == []  # the inputs are intact


def test_full_disk_while_encoding_features_leaves_nothing(tmp_path, monkeypatch):
    store = tmp_path / "f.zarr"
    write_shard(store, [3, 4], 0)
    out = tmp_path / "feats.zarr"
    disk_full_on_call(monkeypatch, zarr.Array, "__setitem__", 1)  # after the arrays were created
    with pytest.raises(OSError, match=rf"{out}"):
        encode.encode_store(TinyEncoder(), store, out, 2, 2, progress=False, device="cpu")
    assert not out.exists() and no_leftovers(tmp_path)


def test_full_disk_while_merging_demos_leaves_nothing(tmp_path, monkeypatch):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write(a, [0, 1])
    write(b, [5, 6])
    disk_full_on_call(monkeypatch, h5py.Group, "copy", 3)
    with pytest.raises(OSError, match=r"No space left on device"):
        merge([a, b], tmp_path / "m.h5")
    assert not (tmp_path / "m.h5").exists() and not (tmp_path / "m.json").exists() and no_leftovers(tmp_path)
