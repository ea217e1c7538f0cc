"""The config slices the rule files pass as params (ocpipe.config.job_params): each job gets everything its code
reads, and a change to a setting changes the params of exactly the jobs that read it (Snakemake reruns a job whose
params changed)."""

import copy

import numpy as np
import pytest
from test_frames_store import write_shard

from ocpipe.config import job_params as J
from ocpipe.config.experiments import resolve
from ocpipe.config.validate import deep_merge, scene_seed_problems
from ocpipe.encoders import registry
from ocpipe.sim import envs


def every_job(config):
    """Each kind of job's params on ``config``, by job: (rule, camera set or None, encoder or None, experiment)."""
    jobs = {("demos", None, None, None): J.demo_job(config),
            ("evaluation protocol", None, None, None): J.evaluation_protocol(config)}
    for cams in envs.CAMERA_SETS:
        jobs["frames_shard", cams, None, None] = J.frames_shard_job(config, cams)
        for enc in registry.ENCODERS:
            jobs["scenes_shard", cams, enc, None] = J.scenes_job(config, cams, enc)
    for enc in registry.ENCODERS:
        jobs["features", None, enc, None] = (J.encoders_of(config, enc), J.encoding(config))
    for exp in config["experiments"]:
        p = resolve(config, exp)
        jobs["evaluation", p["cams"], p["encoder"], exp] = J.evaluation_job(config, p)
        jobs["train", p["cams"], p["encoder"], exp] = J.training_camera_approx(config, p)
    return jobs


def renders(job):
    return job[0] in ("frames_shard", "scenes_shard", "evaluation")


@pytest.mark.parametrize(("change", "reads"), [
    # one encoder's settings: the jobs that build that encoder, none of another's
    ({"encoders": {"dino": {"image_size": 112}}}, lambda job: job[0] != "train" and str(job[2]).startswith("dino_")),
    ({"encoders": {"spot": {"image_size": 112}}}, lambda job: job[0] != "train" and job[2] == "spot"),
    ({"encoders": {"state": {"tcp_relative": False}}}, lambda job: job[0] != "train" and job[2] == "state"),
    # settings of slots_ssl's training and of the diagnostics: no job here (the checkpoint is an input file)
    ({"encoders": {"slots_ssl": {"num_slots": 5}}}, lambda job: False),
    ({"features": {"attention_pairs": [[0, 0]], "probe_mlp_epochs": 3, "probe_holdout": 0.2}}, lambda job: False),
    ({"features": {"batch_size": 8}}, lambda job: job[0] == "features"),
    ({"features": {"chunk_frames": 8}}, lambda job: job[0] == "features"),
    # the demo generator's step cap: only demos; how cameras draw: everything that renders, never the demos
    ({"sim": {"episode_cap": 299}}, lambda job: job[0] == "demos"),
    ({"sim": {"robot_visual_keep": 0.1}}, renders),
    ({"sim": {"backend": "physx_cuda"}}, lambda job: job[0] == "demos" or renders(job)),
    # a camera: the jobs of the camera sets that have it
    ({"cameras": {"side": {"fov_deg": 80.0}}}, lambda job: renders(job) and job[1] == "dual"),
    ({"cameras": {"base": {"fov_deg": 80.0}}}, renders),
    ({"cameras": {"near": 0.02}}, renders),
    ({"camera_approx": {"side": {"fov_deg": 80.0}}},
     lambda job: job[0] in ("frames_shard", "evaluation", "train") and job[1] == "dual"),
    # frames: what chooses the stores is no job's param; the goal marker is every renderer's
    ({"frames": {"resolutions": [64], "camera_sets": {"PickCube-v1": ["native"]}}}, lambda job: False),
    ({"frames": {"shards": 3}}, lambda job: job[0] == "frames_shard"),
    ({"frames": {"goal_marker_visible": False}}, renders),
    # the scenes' own settings, and the seed bounds they stay clear of
    ({"scenes": {"near_radius": 0.04}}, lambda job: job[0] == "scenes_shard"),
    ({"demos": {"num_demos": 50}}, lambda job: job[0] in ("demos", "scenes_shard")),
    ({"demos": {"shards": 2}}, lambda job: job[0] == "demos"),
    ({"evaluation": {"seed_pool_start": 20000}},
     lambda job: job[0] in ("demos", "scenes_shard", "evaluation protocol")),
    ({"evaluation": {"trivial_steps": 5}}, lambda job: job[0] == "evaluation protocol"),
    ({"evaluation": {"sweep_alpha": 0.5, "failure_rules": {"near_miss_m": 0.2}}}, lambda job: False),
])
def test_a_change_reaches_the_params_of_exactly_the_jobs_that_read_it(default_config, change, reads):
    before = every_job(default_config)
    after = every_job(deep_merge(copy.deepcopy(default_config), change))
    changed = {job for job in before if repr(before[job]) != repr(after[job])}  # Snakemake compares params' repr
    assert changed == {job for job in before if reads(job)}


def test_the_slices_name_the_sections_as_the_config_does(default_config):
    c = default_config
    assert J.encoders_of(c, "slots_ssl") == {} and J.encoders_of(c, "dino_dense") == {"dino": c["encoders"]["dino"]}
    assert J.encoders_of(c, "spot") == {"spot": c["encoders"]["spot"]}
    assert J.encoding(c) == {k: c["features"][k] for k in ("batch_size", "chunk_frames", "dtype", "device")}
    native = J.frames_shard_job(c, "native")
    assert set(native["cameras"]) == {"near", "far", "base"} and set(native["camera_approx"]) == {"base"}
    assert native["frames"] == {k: c["frames"][k] for k in ("shards", "chunk_frames", "goal_marker_visible")}
    assert "episode_cap" not in native["sim"] and "episode_cap" in J.demo_job(c)["sim"]
    # unchanged from before the slices moved here: a demo job's params stay those of existing results
    assert repr(J.demo_job(c)) == repr({"sim": {k: v for k, v in c["sim"].items() if k not in J.RENDER_ONLY_SIM_KEYS},
                                        "demos": c["demos"],
                                        "evaluation": {k: c["evaluation"][k]
                                                       for k in ("seed_pool_start", "seed_pool_size")}})
    with pytest.raises(ValueError, match="unknown encoder 'clip'"):
        J.encoders_of(c, "clip")
    with pytest.raises(ValueError, match="unknown camera set 'mono'"):
        J.cameras_of(c, "mono")


def test_diagnostics_hold_out_episodes_only_of_a_store_slots_ssl_trained_on(default_config):
    assert default_config["encoders"]["slots_ssl"]["train_stores"] == ["PickCube-v1_dual_128"]
    assert J.diagnostics_holdout(default_config, "PickCube-v1_dual_128") == 10
    assert J.diagnostics_holdout(default_config, "StackCube-v1_native_128") is None


class Env:
    """Stands in for the ManiSkill env class: make_env's arguments, nothing simulated."""

    def __init__(self, **kwargs):
        self.kwargs = kwargs


@pytest.mark.parametrize("cams", sorted(envs.CAMERA_SETS))
def test_a_job_builds_the_same_environment_from_its_slice_as_from_the_whole_config(default_config, monkeypatch,
                                                                                    cams):
    monkeypatch.setattr(envs, "_env_class", lambda task: Env)
    monkeypatch.setattr(envs, "_lowpoly_env_class", lambda task: Env)
    monkeypatch.setenv("LP_NUM_THREADS", "1")  # make_env sets it where unset
    c = default_config
    policy = {**resolve(c, "goal2d"), "cams": cams}
    for job in (J.frames_shard_job(c, cams), J.scenes_job(c, cams, "slots_ssl"), J.evaluation_job(c, policy)):
        for camera_set in (cams, None):  # None: the state control's evaluation renders no camera
            made = envs.make_env("PickCube-v1", job, camera_set, 64).kwargs
            assert made == envs.make_env("PickCube-v1", c, camera_set, 64).kwargs
    names = list(envs.CAMERA_SETS[cams])
    for approx in (J.frames_shard_job(c, cams), J.evaluation_job(c, policy),
                   {"camera_approx": J.training_camera_approx(c, policy)}):
        for got, want in zip(envs.approx_camera_matrices(approx, names, 64), envs.approx_camera_matrices(c, names, 64),
                             strict=True):
            # exact: the same numbers through the same arithmetic (NaN for the hand camera, which has no model)
            np.testing.assert_array_equal(got, want)


def test_a_scenes_job_checks_its_seeds_on_its_slice_as_on_the_whole_config(default_config):
    c = copy.deepcopy(default_config)
    assert scene_seed_problems(J.scenes_job(c, "dual", "slots_ssl")) == scene_seed_problems(c) == []
    c["scenes"]["seed_start"] = c["evaluation"]["seed_pool_start"]
    assert scene_seed_problems(J.scenes_job(c, "dual", "slots_ssl")) == scene_seed_problems(c) != []


class Stub:
    def eval(self):
        return self


@pytest.mark.parametrize(("encoder", "weights"), [
    ("slots_ssl", {}), ("state", {}),
    *((f"dino_{r}", {"dino": {"checkpoint": "dino.pth"}}) for r in registry.DINO_READOUTS),
    ("spot", {"spot": {"checkpoint": "spot.pt.tar"}}),
    ("spot", {"spot": {"dino_checkpoint": "dino.pth"}}),  # only DINO weights: the slot module trained on them
])
def test_every_encoder_is_built_from_its_slice_alone(default_config, monkeypatch, tmp_path, encoder, weights):
    """registry.build on the sections the slice holds, weights stubbed: a key it read outside them would fail here,
    not in a job."""
    from ocpipe.encoders import checkpoints, dinosaur, frozen_ssl

    monkeypatch.setattr(checkpoints, "load_dino_vit", lambda path, config_key=None: Stub())
    monkeypatch.setattr(checkpoints, "load_spot", lambda path, config_key=None: (Stub(), Stub()))
    monkeypatch.setattr(dinosaur, "load_slot_module", lambda path: Stub())
    monkeypatch.setattr(frozen_ssl, "FrozenSSLSlots", lambda *args: "slots_ssl from its checkpoint")
    write_shard(tmp_path / "f.zarr", [3], 0)
    sizes = {"dino": {"image_size": 112}, "spot": {"image_size": 112}, "state": {"tcp_relative": False}}
    c = deep_merge(deep_merge(default_config, {"encoders": sizes}), {"encoders": weights})
    enc = registry.build(encoder, J.encoders_of(c, encoder), tmp_path / "f.zarr", "trained.pt")
    if encoder == "slots_ssl":
        assert enc == "slots_ssl from its checkpoint"
    elif encoder == "state":
        assert not enc.tcp_relative
    else:
        assert enc.extra_attrs["image_size"] == 112
