"""The simulator's cameras against the configured look-at poses (renders on CPU through lavapipe)."""

import numpy as np
import pytest
from tolerances import EPS32, reduction_atol

from ocpipe.sim import envs
from ocpipe.sim import projection as P


@pytest.fixture(scope="module")
def pick_env(request):
    from conftest import REPO

    from ocpipe.config import validate as C

    cfg = C.load(REPO / "config" / "config.yaml")
    env = envs.make_env("PickCube-v1", cfg, "dual", 96)
    obs, _ = env.reset(seed=10_001)
    yield cfg, env, obs
    env.close()


def test_simulator_matrices_match_the_configured_look_at_poses(pick_env):
    cfg, _, obs = pick_env
    for cam in ("base", "side"):
        params = obs["sensor_param"][envs.SIM_CAMERA_UID[cam]]
        spec = cfg["cameras"][cam]
        # derived: the simulator's float32 camera pose against float64: the pose rounds once (eps32), then two chained
        # float32 sums, R from the quaternion (<= 4 terms, their sizes summing to <= 3) and -R eye (3 terms, |eye| < 1)
        np.testing.assert_allclose(params["extrinsic_cv"][0].numpy(),
                                   P.extrinsic_look_at(spec["eye"], spec["target"]), rtol=0,
                                   atol=reduction_atol(4, 1.0, depth=2, eps=EPS32) + EPS32)
        # derived: f = (W / 2) / tan(fov / 2) in float32: the FOV's rounding (scaled <= 1.6x by tan near 45 degrees),
        # tan's, the division's and the result's: <= 3 eps32 relative
        np.testing.assert_allclose(params["intrinsic_cv"][0].numpy(), P.intrinsic_from_fov(96, spec["fov_deg"]),
                                   rtol=3 * EPS32, atol=0)
        assert obs["sensor_data"][envs.SIM_CAMERA_UID[cam]]["rgb"].shape == (1, 96, 96, 3)


def test_only_the_requested_cameras_are_rendered(pick_env):
    _, _, obs = pick_env
    assert set(obs["sensor_data"]) == {"base_camera", "side_camera"}


def test_readouts_come_from_the_task(pick_env):
    _, env, _ = pick_env
    r = envs.task_readouts(env)
    # exact: the same poses read again, no step between
    np.testing.assert_array_equal(r["goal_pos"], env.unwrapped.goal_site.pose.p[0].numpy())
    np.testing.assert_array_equal(r["obj_pos"], env.unwrapped.cube.pose.p[0].numpy())  # exact: as above
    assert r["qpos"].shape == (9,) and r["is_grasped"] is False


def test_unknown_camera_set_and_task_are_named(pick_env):
    cfg = pick_env[0]
    with pytest.raises(ValueError, match="unknown camera set 'wrist'"):
        envs.camera_specs(cfg, "wrist")
    with pytest.raises(ValueError, match="unknown task 'PushCube-v1'"):
        envs.make_env("PushCube-v1", cfg, "dual", 64)


def test_a_camera_rendered_alone_gives_the_pixels_it_gives_beside_the_others(pick_env):
    """A policy that reads one camera of its set renders only that one: same state, same image."""
    cfg, env, _ = pick_env
    alone = envs.make_env("PickCube-v1", cfg, "dual", 96, cameras=["side"])
    try:
        obs, _ = alone.reset(seed=10_001)
        both = env.unwrapped.get_obs()
        assert set(obs["sensor_data"]) == {"side_camera"}
        # one-cpu: both images rasterized here (lavapipe's float kernels); another CPU kind could give both other bits
        np.testing.assert_array_equal(obs["sensor_data"]["side_camera"]["rgb"].numpy(),
                                      both["sensor_data"]["side_camera"]["rgb"].numpy())
    finally:
        alone.close()
    with pytest.raises(ValueError, match="not all in camera set 'dual'"):
        envs.make_env("PickCube-v1", cfg, "dual", 64, cameras=["hand"])


@pytest.mark.parametrize("task", envs.TASKS)
def test_a_steps_grasp_flag_is_read_from_its_info_and_equals_the_contact_test(task):
    """The closed loop reads the grasp flag that the step's own evaluate() computed instead of testing contacts
    again: the two agree, and the flag does come from ``info``."""
    from conftest import REPO

    from ocpipe.config import validate as C

    env = envs.make_env(task, C.load(REPO / "config" / "config.yaml"))
    try:
        env.reset(seed=10_002)
        rng = np.random.default_rng(0)
        for _ in range(5):
            _, _, _, _, info = env.step(rng.uniform(-1, 1, (1, 8)).astype(np.float32))
            assert envs.task_readouts(env, info=info)["is_grasped"] == envs.task_readouts(env)["is_grasped"]
        key = "is_grasped" if task == "PickCube-v1" else "is_cubeA_grasped"
        flipped = {**info, key: ~info[key]}
        assert envs.task_readouts(env, info=flipped)["is_grasped"] != envs.task_readouts(env)["is_grasped"]
    finally:
        env.close()
