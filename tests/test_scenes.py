"""Extra labelled scenes for the object read-out: what the scenes store holds, and a policy whose read-out is
fitted on them and then stays frozen."""

import numpy as np
import pytest
import torch
import zarr
from policy_stores import policy_settings, write_stores
from test_frames_store import write_shard
from tolerances import EPS32, reduction_atol

from ocpipe.config import validate as C
from ocpipe.encoders.state import state_tokens
from ocpipe.features import scenes
from ocpipe.policy import readout
from ocpipe.policy.checkpoint import load_policy
from ocpipe.policy.training import train
from ocpipe.sim import envs


class MeanColour:
    """A stand-in frozen encoder: per camera, one token holding the image's mean colour."""

    name = "mean_colour"
    checkpoint = None

    def encode(self, rgb):  # (B, C, H, W, 3) uint8
        return (rgb.float().mean(dim=(2, 3)) / 255)[:, :, None, :], None


def test_scenes_hold_the_reset_scene_drawn_with_a_demo_arm_pose(tmp_path, default_config):
    frames = tmp_path / "f.zarr"
    write_shard(frames, [4, 3], 0)
    out = tmp_path / "s.zarr"
    scenes.render_scenes(MeanColour(), default_config, "PickCube-v1", "dual", 32, frames, out, 3, 50_000, seed=0)
    root = zarr.open_group(str(out), mode="r")
    assert root["tokens"].shape == (3, 2, 1, 3) and root["tokens"].dtype == np.float16
    assert root.attrs["seed_start"] == 50_000 and root.attrs["count"] == 3 and root.attrs["encoder"] == "mean_colour"
    assert not list(tmp_path.glob(".tmp-*"))
    env = envs.make_env("PickCube-v1", default_config, None)
    try:
        for i in range(3):
            env.reset(seed=50_000 + i)
            r = envs.task_readouts(env)
            # exact: where the reset put it: the seed's float32 draw, read back from PhysX with no physics step between
            np.testing.assert_array_equal(root["obj_pos"][i], r["obj_pos"])
            assert np.linalg.norm(root["tcp_pos"][i] - r["tcp_pos"]) > 0.01  # the arm moved off its reset pose
    finally:
        env.close()
    assert np.ptp(root["tokens"][...].astype(np.float32), axis=0).max() > 0  # rendered scenes, not one image
    again = tmp_path / "again.zarr"
    scenes.render_scenes(MeanColour(), default_config, "PickCube-v1", "dual", 32, frames, again, 3, 50_000, seed=0)
    # one-cpu: both stores rendered and encoded here (rasterizer and float32 means); another CPU kind could give other
    # bits to both
    np.testing.assert_array_equal(zarr.open_group(str(again), mode="r")["tokens"][...], root["tokens"][...])


def test_near_scenes_put_the_object_beside_a_demo_hand_at_a_random_yaw(tmp_path, default_config):
    frames = tmp_path / "f.zarr"
    write_shard(frames, [4, 3], 0)
    out = tmp_path / "s.zarr"
    scenes.render_scenes(MeanColour(), default_config, "PickCube-v1", "dual", 32, frames, out, 4, 50_000, seed=0,
                         near_fraction=1.0, near_radius=0.05)
    root = zarr.open_group(str(out), mode="r")
    store = zarr.open_group(str(frames), mode="r")
    demo_obj = store["obj_pos"][...][~store["is_grasped"][...].astype(bool)]
    env = envs.make_env("PickCube-v1", default_config, None)
    try:
        for i, pos in enumerate(root["obj_pos"][...]):
            env.reset(seed=50_000 + i)
            assert np.linalg.norm(pos - envs.task_readouts(env)["obj_pos"]) > 1e-3  # moved off the reset place
            gaps = np.linalg.norm(demo_obj - pos, axis=1)
            # within the radius of a demo frame's object, at that frame's height; derived: the placement and the
            # pose PhysX reads back are a few float32 operations on values under 1 m
            assert gaps.min() <= 0.05 + reduction_atol(4, 1.0, eps=EPS32)
            assert abs(pos[2] - demo_obj[gaps.argmin(), 2]) < reduction_atol(4, 1.0, eps=EPS32)  # derived: as above
    finally:
        env.close()
    yaws = np.degrees(state_tokens(root["obj_pos"][...], root["obj_quat"][...])[:, 0, 0, 3])
    assert np.ptp(yaws) > 0  # turned differently
    assert root.attrs["near_fraction"] == 1.0


def test_shards_merge_into_the_store_one_job_writes(tmp_path, default_config):
    frames = tmp_path / "f.zarr"
    write_shard(frames, [4, 3], 0)
    kw = {"near_fraction": 0.5, "near_radius": 0.05, "progress": False}
    args = (MeanColour(), default_config, "PickCube-v1", "dual", 32, frames)
    scenes.render_scenes(*args, tmp_path / "one.zarr", 5, 50_000, 0, **kw)
    parts = [tmp_path / f"s{s}.zarr" for s in range(3)]
    for s, part in enumerate(parts):
        scenes.render_scenes(*args, part, 5, 50_000, 0, shard=s, shards=3, **kw)
    assert [zarr.open_group(str(p), mode="r")["tokens"].shape[0] for p in parts] == [1, 2, 2]
    assert scenes.merge_scenes(parts[::-1], tmp_path / "merged.zarr") == {"scenes": 5, "shards": 3}
    one, merged = (zarr.open_group(str(tmp_path / n), mode="r") for n in ("one.zarr", "merged.zarr"))
    for k in ("tokens", *scenes.LABELS):
        # one-cpu: shards and the single job rendered the same scenes here; shards from other CPU kinds could differ
        np.testing.assert_array_equal(merged[k][...], one[k][...])
    assert dict(merged.attrs) == dict(one.attrs)
    # a shard of another store (other scene seeds) is refused, and nothing is written
    scenes.render_scenes(*args, tmp_path / "other.zarr", 5, 60_000, 0, shard=2, shards=3, **kw)
    with pytest.raises(ValueError, match=r"other.zarr: not shard 2 of the 3 shards of one scenes store"):
        scenes.merge_scenes([parts[0], parts[1], tmp_path / "other.zarr"], tmp_path / "bad.zarr")
    with pytest.raises(ValueError, match=r"bad.zarr: a scenes store of 3 shards, but shards \[0, 2\] were given "
                       r"\(missing: \[1\]\)"):
        scenes.merge_scenes([parts[0], parts[2]], tmp_path / "bad.zarr")
    assert not (tmp_path / "bad.zarr").exists()


def test_scene_seeds_must_clear_the_demo_seeds_and_the_evaluation_pool(tmp_path, default_config):
    with pytest.raises(ValueError, match=r"scenes.seed_start: scene seeds 10000\.\.10002 overlap the evaluation pool"):
        scenes.render_scenes(MeanColour(), default_config, "PickCube-v1", "dual", 32, tmp_path / "f.zarr",
                             tmp_path / "s.zarr", 3, 10_000, seed=0)
    bad = {**default_config, "scenes": {**default_config["scenes"], "count": 10, "seed_start": 5}}
    with pytest.raises(C.ConfigError, match=r"scenes.seed_start: scene seeds 5\.\.14 overlap the demo seeds"):
        C.validate(bad)
    assert not (tmp_path / "s.zarr").exists()


@pytest.mark.parametrize("key, value", [("readout_scenes", True), ("visual_head", "none")])
def test_readout_options_need_the_object_readout(default_config, key, value):
    x = {"object_readout": False, "readout_scenes": False, key: value}
    cfg = {**default_config, "experiments": {**default_config["experiments"], "x": x}}
    with pytest.raises(C.ConfigError, match=rf"experiments.x.{key}: .* needs object_readout: true"):
        C.validate(cfg)


def _scenes_store(path, n, C, K, D, seed, sha=None):
    """Tokens whose first three dims of camera 0, slot 0 hold the object's position (x 10); the rest is noise."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-0.1, 0.1, (n, 3)).astype(np.float32)
    quat = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    tok = rng.normal(0, 1, (n, C, K, D)).astype(np.float32)
    tok[:, 0, 0, :3] = pos * 10
    root = zarr.open_group(str(path), mode="w", zarr_format=3)
    for name, arr in {"tokens": tok.astype(np.float16), "obj_pos": pos, "obj_quat": quat, "tcp_pos": pos}.items():
        root.create_array(name, shape=arr.shape, dtype=arr.dtype)
        root[name][...] = arr
    root.attrs.update({"checkpoint_sha256": sha})
    return tok, pos, quat


@pytest.mark.parametrize("standardize, yaw_weight", [("token_dims", 1.0), ("element", 0.2)])
def test_a_readout_fitted_on_scenes_reads_them_and_stays_frozen(tmp_path, standardize, yaw_weight):
    feats, frames = write_stores(tmp_path, C=2, K=7, D=16)  # demo tokens are noise: only the scenes teach it
    # 4,000 scenes: over four training seeds the read-out's median error is 0.35-0.37 of the spread (token_dims);
    # with 2,000 it was 0.47-0.51, too near the bound below for a test
    _scenes_store(tmp_path / "s.zarr", 4000, 2, 7, 16, seed=1)
    policy = policy_settings(object_readout=True, readout_scenes=True, epochs=2, save_every=1,
                             readout_standardize=standardize, readout_yaw_weight=yaw_weight)
    train(policy, 0, feats, frames, tmp_path / "run", progress=False, scenes_path=tmp_path / "s.zarr")
    ckpts = [torch.load(tmp_path / "run" / "checkpoints" / f"epoch_000{e}.pt", weights_only=False)["model"]
             for e in (1, 2)]
    readout = [k for k in ckpts[0] if k.startswith("sources.3.readout.")]  # the object source, after the goal
    assert readout and all(torch.equal(ckpts[0][k], ckpts[1][k]) for k in readout)  # exact: frozen, so copies
    # exact: an optimizer step changes some decoder weight by far more than one ulp; equal bits would mean no step
    assert any(not torch.equal(ckpts[0][k], ckpts[1][k]) for k in ckpts[0] if k.startswith("decoder."))

    model, _, _ = load_policy(tmp_path / "run" / "checkpoints" / "epoch_0002.pt")
    tok, pos, quat = _scenes_store(tmp_path / "new.zarr", 300, 2, 7, 16, seed=2)  # scenes it never saw
    with torch.no_grad():
        got = model.normalizer.pose.invert(model.object_pose(torch.from_numpy(tok)))[:, :3].numpy()
    err = np.linalg.norm(got - pos, axis=1)
    mean_err = np.linalg.norm(pos - pos.mean(0), axis=1)
    assert np.median(err) < 0.5 * np.median(mean_err)
    assert state_tokens(pos, quat).shape == (300, 1, 1, 5)


def test_a_scenes_store_of_other_encoder_weights_is_refused(tmp_path):
    feats, frames = write_stores(tmp_path)
    _scenes_store(tmp_path / "s.zarr", 50, 2, 7, 16, seed=1, sha="0" * 64)
    policy = policy_settings(object_readout=True, readout_scenes=True, epochs=1, save_every=1)
    with pytest.raises(ValueError, match=r"s.zarr was encoded by other encoder weights than the features store"):
        train(policy, 0, feats, frames, tmp_path / "run", progress=False, scenes_path=tmp_path / "s.zarr")


def test_a_killed_run_with_a_scenes_readout_resumes_identically_without_refitting_it(tmp_path, monkeypatch):
    feats, frames = write_stores(tmp_path)
    _scenes_store(tmp_path / "s.zarr", 300, 2, 7, 16, seed=1)
    policy = policy_settings(object_readout=True, readout_scenes=True, epochs=4, save_every=2,
                             readout_standardize="element")
    full = train(policy, 0, feats, frames, tmp_path / "full", progress=False, scenes_path=tmp_path / "s.zarr")

    def kill_after_3(epoch):
        if epoch == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(policy, 0, feats, frames, tmp_path / "resumed", progress=False, on_epoch_end=kill_after_3,
              scenes_path=tmp_path / "s.zarr")
    fits = []
    monkeypatch.setattr(readout, "fit_readout", lambda *a, **k: fits.append(1))
    resumed = train(policy, 0, feats, frames, tmp_path / "resumed", progress=False, scenes_path=tmp_path / "s.zarr")
    assert fits == []  # the read-out came back with the resume state
    assert resumed.drop("seconds").equals(full.drop("seconds"))  # one-cpu: two trainings' losses
    a = torch.load(tmp_path / "full" / "checkpoints" / "epoch_0004.pt", weights_only=False)
    b = torch.load(tmp_path / "resumed" / "checkpoints" / "epoch_0004.pt", weights_only=False)
    # every weight and statistic, the read-out's input statistics fitted over demos and scenes among them
    assert "normalizer.readout.mean" in a["model"]
    for k in a["model"]:
        # one-cpu: both trainings ran here, so the same kernels; another CPU kind would give other bits to both
        assert torch.equal(a["model"][k], b["model"][k]), k
