# What the stage files share: wildcard constraints, config slices passed as params (ocpipe.config.job_params: a
# change to a setting reruns exactly the jobs that read it), target lists and every input function.
from ocpipe import paths
from ocpipe.bookkeeping import run_cpu
from ocpipe.config import experiments as _exp
from ocpipe.config import job_params, scheduling
from ocpipe.encoders.registry import ENCODERS, SLOT_ENCODERS
from ocpipe.gallery import selection as gallery_selection
from ocpipe.study import inputs, targets


wildcard_constraints:
    task="PickCube-v1|StackCube-v1",
    cams="dual|native",
    encoder="|".join(ENCODERS),
    res=r"\d+",
    shard=r"\d+",
    exp=r"[A-Za-z0-9][A-Za-z0-9_-]*(@[1-9][0-9]*)?",  # a policy id (paths.policy_id): experiment[@replicate]
    lever=r"[A-Za-z0-9][A-Za-z0-9_-]*(@[1-9][0-9]*)?",  # a lever's policy id (paths.policy_id)


def cfg(*sections):
    """The named top-level config sections, as one dict (a rule's params)."""
    return {s: config[s] for s in sections}


def threads_of(stage):
    return config["compute"][stage]["threads"]


def resources_of(stage):
    """A stage's cluster resources from config `compute` (gpu only where asked for, so CPU-only runs stay
    schedulable everywhere)."""
    c = config["compute"][stage]
    return {k: v for k, v in c.items() if k != "threads" and not (k == "gpu" and not v)}


# a job's params are the config it reads, sliced by ocpipe.config.job_params (each function says what its job
# reads): a change to a setting reruns the jobs that read it, not every job that was handed its section
def evaluation_job_params():
    """The protocol an evaluation job runs: the evaluation section without what only later rules read (failure
    thresholds: `failures`; `sweep_alpha`: `best`)."""
    return job_params.evaluation_protocol(config)


def demo_params():
    """Demo jobs: the demos section, the simulator without what only cameras draw, the evaluation pool's bounds."""
    return job_params.demo_job(config)


def frames_shard_params(w):
    """A frames shard: the rendering simulator, the store's camera set, and the `frames` keys a shard reads."""
    return job_params.frames_shard_job(config, w.cams)


def features_encoders(w):
    """The `encoders` sections building the job's encoder reads (none for slots_ssl: its checkpoint is an input)."""
    return job_params.encoders_of(config, w.encoder)


def diagnostics_holdout(w):
    """The held-out episodes a features store's diagnostics score on (None: a store slots_ssl never trained on)."""
    return job_params.diagnostics_holdout(config, paths.FRAMES_NAME.format(task=w.task, cams=w.cams, res=w.res))


def scene_params(w):
    """What a scenes job reads: the rendering simulator, its camera set, its encoder's sections, the scene count and
    seeds, and only the bounds of the demo and evaluation seeds it must stay clear of."""
    return job_params.scenes_job(config, w.cams, w.encoder)


def evaluation_env(policy):
    """What an evaluation job of ``policy`` builds its environment and encoder from (the protocol aside)."""
    return job_params.evaluation_job(config, policy)


def training_camera_approx(policy):
    """The hand-entered camera models of the policy's camera set (its approximate 2d goal)."""
    return job_params.training_camera_approx(config, policy)


def frames_stores():
    return [
        f"{task}_{cams}_{res}"
        for task in config["tasks"]
        for cams in config["frames"]["camera_sets"].get(task, ["dual"])
        for res in config["frames"]["resolutions"]
    ]


def frames_files(store):
    """A frames store's report and contact sheet."""
    return [paths.named(paths.FRAMES_REPORT, store), paths.named(paths.FRAMES_CONTACT, store)]


def frames_targets():
    return [p for s in frames_stores() for p in (paths.frames_store(s), *frames_files(s))]


def _features_outputs(store, enc):
    out = [paths.features_store(f"{store}_{enc}"), paths.features_diagnostics(f"{store}_{enc}")]
    return out + ([paths.named(paths.ATTENTION_FIGURE, f"{store}_{enc}")] if enc in SLOT_ENCODERS else [])


def features_targets(encoders=("slots_ssl",)):
    """Features stores of the default encoder(s), with their diagnostics and attention maps."""
    return [f for store in frames_stores() for enc in encoders for f in _features_outputs(store, enc)]


def experiment_encoding_targets():
    """Frames and features stores (with diagnostics and attention maps) of every experiment a table can run."""
    out = []
    for exp in targets.experiments_of(config):
        p = _exp.resolve(config, exp)
        store = _exp.frames_store(p)
        for f in [frames_files(store)[0], *_features_outputs(store, p["encoder"])]:
            if f not in out:
                out.append(f)
    return out


def encoder_checkpoint(encoder):
    return _exp.encoder_checkpoint(config, encoder)


def policy_of(w):
    """The resolved policy settings of the job's experiment (``exp``: one of its policies, paths.policy_id)."""
    return _exp.resolve(config, paths.split_policy(w.exp)[0])


def store_priority(stage):
    """Long chains start first, a job of several threads before one-thread ones (ocpipe.config.scheduling): a store
    job of config `compute` ``stage`` by its task and threads."""
    return lambda w: scheduling.task_priority(w.task, config, threads_of(stage))


def policy_priority(stage):
    """Long chains start first, a job of several threads before one-thread ones (ocpipe.config.scheduling): a
    policy's training and evaluation jobs by its settings and the threads of config `compute` ``stage``."""
    return lambda w: scheduling.policy_priority(
        policy_of(w) if w.get("exp") else lever_of(w), config, threads_of(stage)
    )


def training_seed(w):
    """Policy k of an experiment (or lever) trains with seed + k (config `replicates`): policy 0 with the root seed
    itself."""
    return config["seed"] + paths.split_policy(w.get("exp") or w.lever)[1]


def train_inputs(w):
    return train_inputs_of(policy_of(w))


def train_inputs_of(p):
    """A policy's features and frames stores, and the scenes store when its object read-out is fitted on scenes."""
    store = _exp.features_store(p)
    out = {"features": paths.features_store(store), "frames": paths.frames_store(_exp.frames_store(p))}
    if p.get("readout_scenes"):
        out["scenes"] = paths.named(paths.SCENES_STORE, store)
    return out


def eval_inputs(w):
    p = policy_of(w)
    return {
        "checkpoints": paths.CHECKPOINTS.format(exp=w.exp),
        "frames": paths.frames_store(_exp.frames_store(p)),
        "encoder": encoder_checkpoint(p["encoder"]),
    }


def sweep_outputs(exp):
    return inputs.SWEEP.files(config, exp)


def stability_outputs(exp):
    return inputs.STABILITY.files(config, exp)


def failure_inputs(exp):
    """Episodes the taxonomy classifies: a dedicated run, or (failure_episodes: 0) the stability runs."""
    if config["evaluation"]["failure_episodes"]:
        return [paths.FAILURE_RUN.format(exp=exp) + ".episodes.parquet"]
    return stability_outputs(exp)


# levers (workflow/rules/levers.smk)
def lever_of(w):
    """The resolved policy settings of the job's lever (``lever``: one of its policies, paths.policy_id)."""
    return _exp.resolve_lever(config, paths.split_policy(w.lever)[0])


def lever_train_inputs(w):
    return train_inputs_of(lever_of(w))


def lever_trained_in(pid):
    """The folder holding a lever policy's checkpoints and train log. A lever without overrides is its experiment's
    baseline: the same settings and seed train the same policy, so its policy k reads the experiment's policy k."""
    lever, k = paths.split_policy(pid)
    spec = config["levers"]["sets"][lever]
    if not spec.get("policy"):
        return paths.RUN.format(exp=paths.policy_id(spec["experiment"], k))
    return paths.LEVER.format(lever=pid)


def lever_eval_inputs(w):
    p = lever_of(w)
    return {
        "checkpoints": f"{lever_trained_in(w.lever)}/checkpoints",
        "frames": paths.frames_store(_exp.frames_store(p)),
        "encoder": encoder_checkpoint(p["encoder"]),
    }


LEVER_FILES = {
    name: [
        (
            f"{lever_trained_in(pid)}/train_log.parquet",
            f"{paths.LEVER_EVAL}.episodes.parquet".format(lever=pid),
            f"{paths.LEVER_EVAL}.steps.parquet".format(lever=pid),
        )
        for pid in (paths.policy_id(name, k) for k in range(config["levers"]["replicates"]))
    ]
    for name in config["levers"].get("build") or config["levers"]["sets"]
}


# the gallery (workflow/rules/gallery.smk)
# experiment -> {table: its row label}, over the tables the gallery covers (rows the config cannot run left out)
GALLERY_ROWS = gallery_selection.rows(config)


def gallery_runs(exp):
    """Policy id -> the evaluation runs its failure classes were read from (episodes files; steps files beside)."""
    return {pid: failure_inputs(pid) for pid in targets.policies(config, exp)}


def gallery_inputs(w):
    """Each policy's failure classes and classified runs, and, for a slot encoder, what its masks are computed with."""
    p = policy_of(w)
    runs = gallery_runs(w.exp)
    out = {
        "classes": [paths.FAILURES.format(exp=pid) for pid in runs],
        "episodes": [f for files in runs.values() for f in files],
        "steps": [paths.steps_beside(f) for files in runs.values() for f in files],
    }
    if p["encoder"] in SLOT_ENCODERS:
        out["frames"] = paths.frames_store(_exp.frames_store(p))
        out["encoder"] = encoder_checkpoint(p["encoder"])
    return out


def gallery_group(w):
    return gallery_selection.row_title(GALLERY_ROWS[w.exp])


def gallery_targets(scope):
    """The galleries of a group target's rows (gallery_selection.SCOPES: `main` or `stackcube`)."""
    return gallery_selection.outputs(gallery_selection.rows(config, (scope,)))


def built_gallery(scope):
    """The part of gallery_targets(scope) already drawn: its group target lists it, so its report shows it."""
    return gallery_selection.built(gallery_selection.rows(config, (scope,)))


def keep_run_cpu(log):
    """The onsuccess/onerror handlers' one step: the run's jobs' CPU as the kernel counted it, which the benchmark
    files undercount (ocpipe.bookkeeping.run_cpu); only the process that ran the jobs here can count them."""
    run_cpu.record(log, workflow.local_exec and not (workflow.remote_exec or workflow.subprocess_exec))
