"""Where every artifact lives: the one source of path patterns, read by the rule files (as wildcard patterns) and
by the code that finds a run's files (filled in with ``str.format``).

Fields: ``task`` (PickCube-v1, ...), ``cams`` (dual | native), ``res`` (pixels), ``encoder``, ``shard``,
``exp`` (one trained policy of an experiment of config ``experiments``: ``policy_id``), ``run`` (a stability run),
``table``, ``figure``. A frames store's name ``{task}_{cams}_{res}`` is what config
`encoders.slots_ssl.train_stores` lists."""

from __future__ import annotations

RESULTS = "results"

# demos: one .h5 of trajectories, its .json of episode metadata and a .report.json per task (and per shard)
DEMO_SHARD = RESULTS + "/demos/shards/{task}/shard{shard}"
DEMOS = RESULTS + "/demos/{task}"

# frames: replayed, rendered episodes (the contract: docs/pipeline.md, "Frames store contract")
FRAMES_SHARD = RESULTS + "/frames/shards/{task}_{cams}_{res}/shard{shard}"
FRAMES_STORE = RESULTS + "/frames/{task}_{cams}_{res}.zarr"
FRAMES_REPORT = RESULTS + "/frames/{task}_{cams}_{res}.report.json"
FRAMES_CONTACT = RESULTS + "/frames/{task}_{cams}_{res}.contact.png"

# frozen encoders trained by the workflow
SLOTS_SSL = RESULTS + "/encoders/slots_ssl"
SPOT_SLOTS = RESULTS + "/encoders/spot"

# features: one store per (frames store, encoder), with its diagnostics and attention maps
FEATURES_STORE = RESULTS + "/features/{task}_{cams}_{res}_{encoder}.zarr"
FEATURES_DIAGNOSTICS = RESULTS + "/features/{task}_{cams}_{res}_{encoder}.diagnostics.json"
ATTENTION_FIGURE = RESULTS + "/figures/attention_{task}_{cams}_{res}_{encoder}.png"
# extra labelled scenes encoded by a features store's encoder, for the object read-out (policy.readout_scenes)
SCENES_STORE = RESULTS + "/features/{task}_{cams}_{res}_{encoder}.scenes.zarr"
SCENES_SHARD = RESULTS + "/features/shards/{task}_{cams}_{res}_{encoder}.scenes_shard{shard}.zarr"  # merged into it

# one folder per trained policy (policy_id): training, then evaluation
RUNS = RESULTS + "/runs"
RUN = RUNS + "/{exp}"
CHECKPOINTS = RUN + "/checkpoints"
TRAIN_LOG = RUN + "/train_log.parquet"
SWEEP = RUN + "/sweep"  # .episodes.parquet and .steps.parquet: every saved checkpoint, on the same seeds
BEST = RUN + "/best.json"
STABILITY = RUN + "/stability/run_{run}"  # .episodes.parquet and .steps.parquet
# an evaluation run's two files: one row per episode, one per step
EPISODES, STEPS = ".episodes.parquet", ".steps.parquet"
FAILURE_RUN = RUN + "/failure_run"
TRAIN_SEEDS = RUN + "/train_seeds"
TRAINING_TIME = RUN + "/training_time"  # Table 5.5's one run on the best checkpoint
FAILURES = RUN + "/failures.parquet"

LEVER = RESULTS + "/levers/{lever}"  # one lever: checkpoints/, train_log.parquet, validation.*.parquet
LEVER_EVAL = LEVER + "/validation"  # .episodes.parquet and .steps.parquet
TABLE = RESULTS + "/tables/{table}"  # .csv and .md (findings: TABLE_DIR/{scope})
TABLE_DIR = RESULTS + "/tables"
FIGURE = RESULTS + "/figures/{figure}.png"
# one experiment's gallery (a row of Tables 5.1/5.2 or 5.10/5.11): videos/, sheets/ and episodes.csv
GALLERY = RESULTS + "/gallery/{exp}"


FRAMES_NAME = "{task}_{cams}_{res}"  # a frames store's name, as config `encoders.slots_ssl.train_stores` lists it
FEATURES_NAME = FRAMES_NAME + "_{encoder}"  # a features store's name


def steps_beside(episodes_file) -> str:
    """The steps file of the evaluation run whose episodes file this is."""
    name = str(episodes_file)
    if not name.endswith(EPISODES):
        raise ValueError(f"{name}: not an evaluation run's episodes file (*{EPISODES})")
    return name.removesuffix(EPISODES) + STEPS


def named(pattern: str, name: str) -> str:
    """A pattern with a store's name in place of its fields: a features store name ``{task}_{cams}_{res}_{encoder}``
    where the pattern has those four, a frames store name ``{task}_{cams}_{res}`` where it has three."""
    fields = FEATURES_NAME if FEATURES_NAME in pattern else FRAMES_NAME
    if fields not in pattern:
        raise ValueError(f"{pattern!r} has no store name fields")
    return pattern.replace(fields, name)


def frames_store(name: str) -> str:
    """The frames store path of a store name ``{task}_{cams}_{res}``."""
    return named(FRAMES_STORE, name)


def features_store(name: str) -> str:
    """The features store path of a name ``{task}_{cams}_{res}_{encoder}``."""
    return named(FEATURES_STORE, name)


def features_diagnostics(name: str) -> str:
    """The diagnostics report of a features store name ``{task}_{cams}_{res}_{encoder}``."""
    return named(FEATURES_DIAGNOSTICS, name)


def in_runs(pattern: str, runs_dir, **fields) -> str:
    """A RUN-relative pattern filled in, under another runs folder than results/runs when asked."""
    return pattern.replace(RESULTS + "/runs", str(runs_dir), 1).format(**fields)


REPLICATE_MARK = "@"  # experiment names cannot hold it (config schema), so a policy id splits back unambiguously


def policy_id(exp: str, replicate: int) -> str:
    """The id (and runs folder name) of an experiment's policy number ``replicate``: policy 0 is the experiment's own
    name, so a build of one policy per experiment keeps the folders it always had; policy k > 0 is ``exp@k``."""
    if replicate < 0:
        raise ValueError(f"policy {replicate} of {exp}: replicate indices start at 0")
    return exp if replicate == 0 else f"{exp}{REPLICATE_MARK}{replicate}"


def split_policy(pid: str) -> tuple[str, int]:
    """(experiment, replicate index) of a policy id."""
    exp, mark, k = pid.partition(REPLICATE_MARK)
    if mark and not (k.isdigit() and int(k) > 0 and str(int(k)) == k):
        raise ValueError(f"policy id {pid!r}: expected experiment@k with k a positive integer")
    return exp, int(k) if mark else 0
