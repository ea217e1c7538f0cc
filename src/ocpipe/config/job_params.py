"""What each of the workflow's jobs reads of the config: the slices the rule files pass as a job's params.

Snakemake reruns a job when its params change, so a job's params hold what its code reads and nothing more:
changing a setting reruns the jobs that read it (and, through their outputs, what depends on them), never a job
that was only handed the setting's section. Each function returns the part of the config one kind of job reads,
with the config's own key names, so a script hands it on where the code expects the config (every key the code
looks up is there: tests/test_job_params.py builds environments and encoders from the slices). Plain dicts:
Snakemake compares a param by its repr. Knows nothing of Snakemake; workflow/rules/common.smk calls it."""

from __future__ import annotations

from ..encoders.registry import CONFIG_SECTIONS
from ..sim.envs import CAMERA_SETS

# sim keys that change only what the cameras draw: demo generation renders nothing
RENDER_ONLY_SIM_KEYS = ("lavapipe_threads", "robot_visual_keep", "ground_cells")
# sim keys that only demo generation reads: the motion planner's step cap (a replay steps through a demo's own
# actions, an evaluation episode stops at evaluation.episode_cap, the scenes step nothing)
DEMO_ONLY_SIM_KEYS = ("episode_cap",)
# read after the episodes are run (failure classification, the best checkpoint's choice), never by an evaluation job
EVALUATION_KEYS_READ_LATER = ("failure_rules", "sweep_alpha")
# what encoding a features store reads of `features` (attention_pairs and probe_*: the attention maps' and the
# diagnostics' own, passed to those rules alone)
ENCODING_KEYS = ("batch_size", "chunk_frames", "dtype", "device")
# what replaying and rendering a frames shard reads of `frames` (resolutions and camera_sets only choose which
# stores there are: the job's wildcards)
FRAMES_SHARD_KEYS = ("shards", "chunk_frames", "goal_marker_visible")
# every camera a camera set can name (config `cameras` and `camera_approx` hold the fixed ones among them)
CAMERAS = tuple(dict.fromkeys(c for names in CAMERA_SETS.values() for c in names))


def _pick(section: dict, keys) -> dict:
    return {k: section[k] for k in keys}


def _without(section: dict, keys) -> dict:
    return {k: v for k, v in section.items() if k not in keys}


def _pool_bounds(config: dict) -> dict:
    """Of the evaluation pool only its bounds: what a job that draws seeds of its own must stay clear of."""
    return _pick(config["evaluation"], ("seed_pool_start", "seed_pool_size"))


def rendering_sim(config: dict) -> dict:
    """`sim` as a job that renders (frames, scenes, evaluation) reads it: all but the demo generator's step cap."""
    return _without(config["sim"], DEMO_ONLY_SIM_KEYS)


def cameras_of(config: dict, camera_set: str) -> dict:
    """`cameras` and `camera_approx` as a job of ``camera_set`` reads them (sim.envs.make_env, camera_specs and
    approx_camera_matrices): the clip planes and the set's own cameras, not another set's (a change to the side
    camera leaves the native stores, base + hand, as they are)."""
    if camera_set not in CAMERA_SETS:
        raise ValueError(f"unknown camera set {camera_set!r}; known: {', '.join(CAMERA_SETS)}")
    others = set(CAMERAS) - set(CAMERA_SETS[camera_set])
    return {"cameras": _without(config["cameras"], others), "camera_approx": _without(config["camera_approx"], others)}


def encoders_of(config: dict, encoder: str) -> dict:
    """The `encoders` sections building ``encoder`` reads (encoders.registry.build): none for slots_ssl, whose
    checkpoint is an input file (train_slots_ssl reads its settings), only `dino` for the DINO readouts."""
    if encoder not in CONFIG_SECTIONS:
        raise ValueError(f"unknown encoder {encoder!r}; known: {', '.join(CONFIG_SECTIONS)}")
    return _pick(config["encoders"], CONFIG_SECTIONS[encoder])


def evaluation_protocol(config: dict) -> dict:
    """The protocol an evaluation job runs: the evaluation section without what only later rules read, so changing
    a failure threshold reruns `failures` and changing `sweep_alpha` reruns `best`, not one episode."""
    return _without(config["evaluation"], EVALUATION_KEYS_READ_LATER)


def demo_job(config: dict) -> dict:
    """A demo job (demos_shard, demos_import): the demos section and the simulator without what only the cameras
    draw (demo generation renders nothing); of the evaluation pool only its bounds, which demo seeds keep out of."""
    return {"sim": _without(config["sim"], RENDER_ONLY_SIM_KEYS), "demos": config["demos"],
            "evaluation": _pool_bounds(config)}


def frames_shard_job(config: dict, camera_set: str) -> dict:
    """A frames shard (frames.render.render_shard): the rendering simulator, the set's cameras and their
    hand-entered models (the store keeps the approximate 2d goal), and the shard count, chunk length and goal
    marker of `frames`."""
    return {"sim": rendering_sim(config), "frames": _pick(config["frames"], FRAMES_SHARD_KEYS),
            **cameras_of(config, camera_set)}


def encoding(config: dict) -> dict:
    """What encoding a features store reads of `features` (features.encode.encode_store)."""
    return _pick(config["features"], ENCODING_KEYS)


def diagnostics_holdout(config: dict, frames_store: str) -> int | None:
    """The episodes at the end of ``frames_store`` (``{task}_{cams}_{res}``) that a features store's diagnostics
    score decomposition on: those slots_ssl never trained on where the store is one of its training stores, else
    None (every episode: the encoder saw none of them)."""
    enc = config["encoders"]["slots_ssl"]
    return enc["holdout_episodes"] if frames_store in enc["train_stores"] else None


def scenes_job(config: dict, camera_set: str, encoder: str) -> dict:
    """A scenes shard (features.scenes.render_scenes): the rendering simulator, the set's cameras (the scenes keep no
    2d goal, so no camera_approx), the goal marker, the encoder's sections, the scenes section, and only the bounds
    of the demo seeds and evaluation pool it must stay clear of."""
    demos = _pick(config["demos"], ("seed_start", "num_demos", "attempts_per_demo"))
    return {"sim": rendering_sim(config), "cameras": cameras_of(config, camera_set)["cameras"],
            "encoders": encoders_of(config, encoder), "scenes": config["scenes"],
            "frames": {"goal_marker_visible": config["frames"]["goal_marker_visible"]}, "demos": demos,
            "evaluation": _pool_bounds(config)}


def evaluation_job(config: dict, policy: dict) -> dict:
    """The environment and encoder an evaluation job of ``policy`` (its resolved settings) builds
    (evaluation.closed_loop.ClosedLoop): the rendering simulator, the cameras and hand-entered models of the
    policy's camera set, the goal marker and its encoder's sections. The protocol is `evaluation_protocol`."""
    return {"sim": rendering_sim(config), **cameras_of(config, policy["cams"]),
            "frames": {"goal_marker_visible": config["frames"]["goal_marker_visible"]},
            "encoders": encoders_of(config, policy["encoder"])}


def training_camera_approx(config: dict, policy: dict) -> dict:
    """`camera_approx` as training ``policy`` reads it (the approximate 2d goal of its camera set's cameras)."""
    return cameras_of(config, policy["cams"])["camera_approx"]
