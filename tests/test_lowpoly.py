"""Decimated robot visuals (sim.robot_visual_keep, sim.ground_cells): a reproducible cache, fewer triangles, and the
same physics (renders on CPU through lavapipe)."""

import copy
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import torch

from ocpipe.sim import envs, lowpoly


def _panda_urdf() -> Path:
    from mani_skill.agents.robots import Panda

    return Path(Panda.urdf_path)


def _visual_triangles(urdf: Path) -> int:
    import trimesh

    total = 0
    for m in lowpoly._visual_meshes(ET.parse(urdf).getroot()):
        scene = trimesh.load(str(urdf.parent / m.get("filename")), force="scene")
        total += sum(len(scene.geometry[scene.graph[n][1]].faces) for n in scene.graph.nodes_geometry)
    return total


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("lowpoly")
    return root, lowpoly.decimated_urdf(_panda_urdf(), 0.1, root)


def test_decimated_urdf_is_reproducible(built, tmp_path):
    root, urdf = built
    again = lowpoly.decimated_urdf(_panda_urdf(), 0.1, tmp_path)
    assert again.parent.name == urdf.parent.name  # same hash: the cache key does not depend on where it is built
    # one-cpu: two decimations on this machine, byte for byte (the simplifier's float kernels decide the vertices)
    assert _files(again.parent) == _files(urdf.parent)
    assert lowpoly.decimated_urdf(_panda_urdf(), 0.1, root) == urdf  # cached: returned, not rebuilt
    assert not list(root.glob(".build-*"))  # no temp dirs left behind


def test_triangles_drop_by_about_keep(built):
    _, urdf = built
    before, after = _visual_triangles(_panda_urdf()), _visual_triangles(urdf)
    assert before > 100_000
    assert 0.08 < after / before < 0.13


def test_collision_meshes_are_the_originals_and_the_srdf_is_copied(built):
    _, urdf = built
    root = ET.parse(urdf).getroot()
    collisions = [m.get("filename") for c in root.iter("collision") for m in c.iter("mesh")]
    assert collisions
    for f in collisions:
        assert Path(f).is_absolute() and Path(f).is_file(), f
        assert Path(f).is_relative_to(_panda_urdf().parent)
    for f in (m.get("filename") for m in lowpoly._visual_meshes(root)):
        assert (urdf.parent / f).is_file(), f
    # exact: a copied file
    assert (urdf.parent / "panda_v2.srdf").read_bytes() == _panda_urdf().with_suffix(".srdf").read_bytes()


def test_a_copy_built_from_another_install_is_not_reused(tmp_path):
    """The copy names the original collision meshes by absolute path: one built from a robot elsewhere (another
    clone's venv) gets its own key, and a cached copy whose originals are gone is refused, not loaded."""
    elsewhere = tmp_path / "other_install"
    shutil.copytree(_panda_urdf().parent, elsewhere)
    root = tmp_path / "cache"
    moved = lowpoly.decimated_urdf(elsewhere / _panda_urdf().name, 0.1, root)
    assert lowpoly.decimated_urdf(_panda_urdf(), 0.1, root).parent != moved.parent
    shutil.rmtree(elsewhere / "franka_description" / "meshes" / "collision")
    with pytest.raises(FileNotFoundError, match=r"the cached robot names .*collision.* which no longer exists"):
        lowpoly.decimated_urdf(elsewhere / _panda_urdf().name, 0.1, root)


def test_bad_keep_is_refused(tmp_path):
    with pytest.raises(ValueError, match="keep must be in"):
        lowpoly.decimated_urdf(_panda_urdf(), 0.0, tmp_path)


@pytest.fixture
def cache_home(tmp_path, monkeypatch):
    """A fresh default cache root; agent_class memoizes its path, so forget it before and after."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    lowpoly.agent_class.cache_clear()
    yield tmp_path
    lowpoly.agent_class.cache_clear()


def test_lowpoly_env_has_the_same_physics_and_segmentation(default_config, cache_home):
    import sapien

    low, plain = copy.deepcopy(default_config), copy.deepcopy(default_config)
    low["sim"]["robot_visual_keep"], low["sim"]["ground_cells"] = 0.1, 2
    plain["sim"]["robot_visual_keep"], plain["sim"]["ground_cells"] = None, None  # as ManiSkill draws the scene
    plain_env = envs.make_env("PickCube-v1", plain, "dual", 64)
    low_env = envs.make_env("PickCube-v1", low, "dual", 64, obs_mode="rgb+segmentation")
    try:
        u_plain, u_low = plain_env.unwrapped, low_env.unwrapped
        assert type(u_plain) is envs._env_class("PickCube-v1")  # no keys: today's class
        assert type(u_low).__mro__[1] is lowpoly.LowPolyAgentMixin
        assert isinstance(u_low, envs._env_class("PickCube-v1"))
        assert Path(u_low.agent.urdf_path).is_relative_to(cache_home)
        assert ({i: o.name for i, o in u_plain.segmentation_id_map.items()}
                == {i: o.name for i, o in u_low.segmentation_id_map.items()})
        ground = u_low.table_scene.ground._objs[0].find_component_by_type(sapien.render.RenderBodyComponent)
        assert len(ground.render_shapes[0].parts[0].triangles) == 2 * 2 * 2  # a 2 x 2 grid of squares

        plain_env.reset(seed=10_001)
        low_env.reset(seed=10_001)
        rng = np.random.default_rng(0)
        for _ in range(5):
            action = torch.as_tensor(rng.uniform(-0.5, 0.5, (1, 8)), dtype=torch.float32)
            _, r_plain, *_ = plain_env.step(action)
            obs, r_low, *_ = low_env.step(action)
            a, b = envs.task_readouts(plain_env), envs.task_readouts(low_env)
            for k in a:
                # one-cpu: the same PhysX steps on the same collision meshes and actions, both envs in this process
                # (only the visual meshes differ, physics never reads them); the bits follow the CPU's kernels
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)
            assert torch.equal(r_plain, r_low)  # one-cpu: the rewards of those same steps
        seg = obs["sensor_data"]["base_camera"]["segmentation"]
        assert set(torch.unique(seg).tolist()) <= set(u_low.segmentation_id_map) | {0}
    finally:
        plain_env.close()
        low_env.close()


def test_camera_less_env_stays_plain(default_config):
    cfg = copy.deepcopy(default_config)
    cfg["sim"]["robot_visual_keep"], cfg["sim"]["ground_cells"] = 0.1, 2
    env = envs.make_env("PickCube-v1", cfg, None)
    try:
        assert type(env.unwrapped) is envs._env_class("PickCube-v1")
    finally:
        env.close()


def test_plain_mesh_files_stay_in_their_format(tmp_path):
    """The wrist-camera Panda (StackCube's hand camera) has an STL camera body coloured by its URDF <material>:
    it is decimated into an STL again, so the loader colours it the same way."""
    import trimesh
    from mani_skill.agents.registration import REGISTERED_AGENTS

    urdf = Path(REGISTERED_AGENTS["panda_wristcam"].agent_cls.urdf_path)
    out = lowpoly.decimated_urdf(urdf, 0.1, tmp_path)
    meshes = [m.get("filename") for m in lowpoly._visual_meshes(ET.parse(out).getroot())]
    stl = [f for f in meshes if f.endswith(".stl")]
    assert len(stl) == 1
    before = trimesh.load(str(urdf.parent / "realsense2_description/meshes/d415.stl"))
    after = trimesh.load(str(out.parent / stl[0]))
    assert 0.05 < len(after.faces) / len(before.faces) < 0.15
