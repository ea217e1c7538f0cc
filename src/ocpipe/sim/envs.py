"""ManiSkill environments with the study's cameras (docs/study.md, Cameras) and task-specific readouts."""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass

import numpy as np

TASKS = ("PickCube-v1", "StackCube-v1")
CAMERA_SETS = {"dual": ("base", "side"), "native": ("base", "hand")}
# ManiSkill's uid for each of our camera names.
SIM_CAMERA_UID = {"base": "base_camera", "side": "side_camera", "hand": "hand_camera"}


@dataclass(frozen=True)
class CameraSpec:
    name: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    fov_deg: float


def camera_specs(config: dict, camera_set: str) -> list[CameraSpec]:
    """Fixed cameras of a camera set from config (the hand camera is the robot's own and has no spec)."""
    if camera_set not in CAMERA_SETS:
        raise ValueError(f"unknown camera set {camera_set!r}; known: {', '.join(CAMERA_SETS)}")
    cams = config["cameras"]
    return [
        CameraSpec(name, tuple(cams[name]["eye"]), tuple(cams[name]["target"]), float(cams[name]["fov_deg"]))
        for name in CAMERA_SETS[camera_set]
        if name != "hand"
    ]


def approx_camera_matrices(config: dict, cameras: list[str], resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """(C, 3, 3) intrinsics and (C, 3, 4) extrinsics of the hand-entered camera model (config camera_approx).

    Cameras without a hand-entered model (the moving hand camera) get NaN: no approx goal, not a guess."""
    from . import projection

    approx = config["camera_approx"]
    K = [projection.intrinsic_from_fov(resolution, approx[c]["fov_deg"]) if c in approx else np.full((3, 3), np.nan)
         for c in cameras]
    E = [projection.extrinsic_look_at(approx[c]["eye"], approx[c]["target"]) if c in approx
         else np.full((3, 4), np.nan) for c in cameras]
    return np.stack(K), np.stack(E)


@functools.cache
def _env_class(task: str):
    import mani_skill.envs  # noqa: F401  (registers the tasks)
    from mani_skill.envs.tasks import PickCubeEnv, StackCubeEnv

    base = {"PickCube-v1": PickCubeEnv, "StackCube-v1": StackCubeEnv}[task]

    class StudyEnv(base):
        """The task with the study's fixed cameras, an optional visible goal marker and a chosen sensor set."""

        def __init__(self, *args, study_cameras=(), keep_sensors=None, goal_visible=False, near=0.01, far=100.0,
                     resolution=128, **kwargs):
            self._study_cameras = tuple(study_cameras)
            self._keep_sensors = None if keep_sensors is None else set(keep_sensors)
            self._goal_visible = goal_visible
            self._near, self._far, self._resolution = near, far, resolution
            super().__init__(*args, **kwargs)

        @property
        def _default_sensor_configs(self):
            from mani_skill.sensors.camera import CameraConfig
            from mani_skill.utils import sapien_utils

            return [
                CameraConfig(SIM_CAMERA_UID[c.name], sapien_utils.look_at(eye=c.eye, target=c.target),
                             self._resolution, self._resolution, np.deg2rad(c.fov_deg), self._near, self._far)
                for c in self._study_cameras
            ]

        def _setup_sensors(self, options):
            super()._setup_sensors(options)
            if self._keep_sensors is not None:
                # scene.sensors is this same dict, so dropping entries here also stops them being rendered
                for uid in list(self._sensors):
                    if uid not in self._keep_sensors:
                        del self._sensors[uid]
                        del self._sensor_configs[uid]

        def _load_scene(self, options):
            super()._load_scene(options)
            if self._goal_visible and task == "PickCube-v1" and self.goal_site in self._hidden_objects:
                self._hidden_objects.remove(self.goal_site)

    StudyEnv.__name__ = StudyEnv.__qualname__ = f"Study{base.__name__}"
    return StudyEnv


@functools.cache
def _lowpoly_env_class(task: str):
    """The study env with coarser robot and ground visuals (sim.robot_visual_keep / sim.ground_cells): fewer
    triangles for lavapipe to draw; collision shapes, and so physics, are untouched."""
    from . import lowpoly

    base = _env_class(task)
    # a subclass, so isinstance(env, _env_class(task)) still holds (task_readouts relies on it)
    return type(f"LowPoly{base.__name__}", (lowpoly.LowPolyAgentMixin, base), {"__module__": __name__})


def make_env(task: str, config: dict, camera_set: str | None = None, resolution: int = 128, obs_mode: str = "rgb",
             cameras: list[str] | None = None):
    """A single physx_cpu environment of ``task`` with the cameras of ``camera_set`` rendered at ``resolution``
    (``cameras``: only these of the set, e.g. the ones a policy reads; a camera is about a fifth of an evaluation
    step's CPU time).

    ``camera_set=None`` renders no cameras (demo generation). No TimeLimit wrapper: callers enforce
    ``sim.episode_cap`` themselves, so the registered 50-step limit can never truncate an expert."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known: {', '.join(TASKS)}")
    sim = config["sim"]
    if sim.get("lavapipe_threads") is not None:
        # Mesa's CPU Vulkan driver reads this once, when it loads; a value in the caller's environment wins.
        # GPU drivers ignore it.
        os.environ.setdefault("LP_NUM_THREADS", str(sim["lavapipe_threads"]))
    cams = camera_specs(config, camera_set) if camera_set else []
    keep = [SIM_CAMERA_UID[n] for n in CAMERA_SETS[camera_set] if cameras is None or n in cameras] if camera_set else []
    if camera_set and cameras is not None and len(keep) != len(set(cameras)):
        raise ValueError(f"cameras {list(cameras)} are not all in camera set {camera_set!r} "
                         f"({', '.join(CAMERA_SETS[camera_set])})")
    sensor_overrides = {"shader_pack": sim["shader"]}
    if camera_set and "hand" in CAMERA_SETS[camera_set]:
        sensor_overrides["hand_camera"] = {"width": resolution, "height": resolution}
    cls, extra = _env_class(task), {}
    lowpoly = {k: sim.get(k) for k in ("robot_visual_keep", "ground_cells") if sim.get(k) is not None}
    if camera_set and lowpoly:
        # only what the cameras see changes; a camera-less env (demo generation) has nothing to gain
        cls, extra = _lowpoly_env_class(task), lowpoly
    return cls(
        study_cameras=cams, keep_sensors=keep, goal_visible=config["frames"]["goal_marker_visible"],
        near=config["cameras"]["near"], far=config["cameras"]["far"], resolution=resolution,
        obs_mode=obs_mode if camera_set else "state_dict", control_mode=sim["control_mode"],
        sim_backend=sim["backend"], num_envs=1, render_mode=None,
        sensor_configs=sensor_overrides, **extra,
    )


def make_viewer_env(task: str, config: dict, resolution: int, shader: str = "default"):
    """An environment to watch ``task`` in, not a policy's: no sensor cameras, the original robot meshes whatever
    sim.robot_visual_keep says, the floor as sim.ground_cells draws it (the same texture: a 100 x 100 grid costs a
    fifth of a frame), and ManiSkill's human render camera (``env.render()``) at ``resolution`` with the ``shader``
    pack. It shows what cameras hide (PickCube's goal sphere). Physics as make_env's."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known: {', '.join(TASKS)}")
    sim = config["sim"]
    cells = sim.get("ground_cells")
    cls, extra = (_lowpoly_env_class(task), {"ground_cells": cells}) if cells is not None else (_env_class(task), {})
    return cls(
        goal_visible=config["frames"]["goal_marker_visible"], keep_sensors=[], obs_mode="state_dict",
        control_mode=sim["control_mode"], sim_backend=sim["backend"], num_envs=1, render_mode="rgb_array",
        human_render_camera_configs={"width": resolution, "height": resolution, "shader_pack": shader}, **extra,
    )


def task_object(env):
    """The actor the task manipulates (PickCube's cube, StackCube's cubeA)."""
    u = env.unwrapped
    return u.cube if isinstance(u, _env_class("PickCube-v1")) else u.cubeA


def task_readouts(env, after_reset: bool = False, info: dict | None = None) -> dict[str, np.ndarray]:
    """Per-step labels read from the simulator (not from obs, which differ by task and obs mode).

    ``after_reset``: no physics step has run since the episode's reset. The grasp test reads contacts, which only a
    physics step computes: until then they are the previous episode's (a demo that ended holding the cube made
    the next episode's first frame 'grasped'). Both tasks start with the gripper open, away from the cubes.
    ``info``: what the step that led here returned; its grasp flag is the same test of the same contacts, so it
    is read instead of testing the contacts a second time (a few percent of a closed-loop step)."""
    u = env.unwrapped
    obj = task_object(env)
    if isinstance(u, _env_class("PickCube-v1")):
        goal, grasp_key = u.goal_site.pose.p, "is_grasped"  # grasp_key: the task's evaluate() output
    else:
        goal, grasp_key = u.cubeB.pose.p.clone(), "is_cubeA_grasped"
        goal[..., 2] += 2 * u.cube_half_size[2]  # top centre of cubeB: where cubeA's centre must go
    if after_reset:
        grasped = False
    else:
        grasped = bool((u.agent.is_grasping(obj) if info is None else info[grasp_key])[0].item())
    return {
        "qpos": u.agent.robot.get_qpos()[0].cpu().numpy(),
        "tcp_pos": u.agent.tcp.pose.p[0].cpu().numpy(),
        "obj_pos": obj.pose.p[0].cpu().numpy(),
        "obj_quat": obj.pose.q[0].cpu().numpy(),  # wxyz
        "goal_pos": goal[0].cpu().numpy(),
        "is_grasped": grasped,
    }
