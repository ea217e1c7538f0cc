"""One experiment's policy settings, typed and grouped by concern: which stores it reads, its goal input, its
visual pathway, its object read-out, the network and its training.

Each setting is declared once, here: its config key (config `policy`, flat, as experiments override it), type,
allowed values and what it does. The config schema's `policy` and `experiments` sections and config/README.md
are generated from these declarations (``schema_properties``); config/config.yaml and config/thesis.yaml give
the values. Checkpoints store the settings as a flat dict, readable without this module; ``PolicySettings.of``
turns one back into settings."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields

from ..encoders.registry import ENCODERS  # the frozen encoders a features store can be made with

# Levers that were measured, lost and were removed, with the value that means "off" (the study's) and the last
# commit that had them (docs/journal.md has their figures). A checkpoint that names one at that value loads;
# one trained with it on cannot be rebuilt by this code.
RETIRED = {"slot_geometry": False, "proprio_noise": 0.0, "first_frame": False, "readout_noise": 0.0,
           "readout_tcp_relative": False}
RETIRED_AT = "19a73bd"


def setting(key: str, schema: dict, doc: str, default=MISSING):
    """A setting: its flat config key, its JSON schema (type and allowed values) and what it does. A default is
    the value that reproduces how a checkpoint written before the setting existed was trained."""
    return field(default=default, metadata={"key": key, "schema": schema, "doc": doc})




def enum(*values) -> dict:
    return {"enum": list(values)}


def integer(minimum: int) -> dict:
    return {"type": "integer", "minimum": minimum}


def number(minimum: float = 0, maximum: float | None = None, exclusive: bool = False) -> dict:
    bound = {"exclusiveMinimum" if exclusive else "minimum": minimum}
    return {"type": "number", **bound, **({"maximum": maximum} if maximum is not None else {})}


@dataclass(frozen=True)
class Stores:
    task: str = setting("task", {"$ref": "#/$defs/task"}, "task the policy is trained and evaluated on")
    cams: str = setting("cams", enum("dual", "native"), "camera set of its frames and features stores")
    resolution: int = setting("resolution", integer(16), "image resolution of its stores, px")
    encoder: str = setting("encoder", enum(*ENCODERS),
                           "frozen encoder of the features store; 'state' is the privileged-state control (object "
                           "pose); the study's is spot, which needs weights")
    cameras: list = setting("cameras", {"type": "array", "items": integer(0), "minItems": 1, "uniqueItems": True},
                            "indices of the store's cameras whose tokens the policy sees (store order: base, then "
                            "side or hand)")


@dataclass(frozen=True)
class Goal:
    kind: str = setting("goal", enum("none", "2d", "3d"),
                        "goal input: none (pure visual), 2d (projected into each camera) or 3d (oracle xyz)")
    calibration: str = setting("goal_calibration", enum("exact", "approx"),
                               "2d goal from the simulator's cameras (exact) or from the hand-entered camera_approx "
                               "model (approx)")
    norm: str = setting("goal_norm", enum("none", "zscore"),
                        "the goal input as given (none: metres for 3d, image fractions for 2d) or zscore: "
                        "standardized per dimension with the training frames' statistics (study: none)", "none")
    relative: str = setting("goal_relative", enum("none", "tcp"),
                            "the goal alone (none), or tcp: also the goal minus the TCP's position, in the goal's "
                            "frame (3d: metres; 2d: projected into each camera with the goal's calibration): how "
                            "far the hand still has to go (study: none)", "none")


@dataclass(frozen=True)
class Visual:
    head: str = setting("visual_head", enum("tokens", "flatten", "deepsets", "weighted_pool", "slot_transformer",
                                            "none"),
                        "visual tokens as they are (tokens, one per slot) or pooled by a head: flatten, deepsets, "
                        "weighted_pool, slot_transformer; none: the frozen tokens reach the policy only through "
                        "its object read-out (study: tokens)")
    fusion: str = setting("fusion", enum("concat", "cross_attention"),
                          "how the two cameras' tokens meet: concat, or cross_attention (bidirectional, per step)")
    token_norm: str = setting("token_norm", enum("none", "zscore"),
                              "zscore: standardize each visual token dimension with training-set statistics "
                              "(study: none)", "none")
    dropout: float = setting("visual_dropout", number(0, 1),
                             "chance that a training step's visual tokens are blanked (set to their mean), so the "
                             "policy learns to act from the object read-out, joints and goal as well (study: 0)",
                             0.0)


@dataclass(frozen=True)
class Readout:
    enabled: bool = setting("object_readout", {"type": "boolean"},
                            "add a token per step from an MLP that reads the object's pose (position, yaw) off that "
                            "step's frozen tokens, trained on the frames store's poses (study: false)", False)
    scenes: bool = setting("readout_scenes", {"type": "boolean"},
                           "fit that read-out first on the training demos' frames plus the scenes store (config "
                           "scenes), then freeze it; needs object_readout (study: false)", False)
    standardize: str = setting("readout_standardize", enum("token_dims", "element"),
                               "how the read-out's input is standardized: token_dims, per token dimension pooled "
                               "over slots and cameras (as token_norm), or element, each slot's and camera's "
                               "dimension on its own (study: no read-out)", "token_dims")
    yaw_weight: float = setting("readout_yaw_weight", number(0),
                                "weight of the yaw terms (sin/cos of 4x yaw) in the read-out's squared-error loss, "
                                "the position's being 1 (study: no read-out)", 1.0)


@dataclass(frozen=True)
class Network:
    proprio: str = setting("proprio", enum("joints7", "qpos9_global", "qpos9_grouped", "joints7_tcp"),
                           "proprioception: joints7 (7 arm joints), qpos9_global (9 dims, one z-score), "
                           "qpos9_grouped (joints and fingers z-scored apart) or joints7_tcp (7 joints and the "
                           "gripper's xyz)")
    window: int = setting("window", integer(1), "T: past timesteps per sample")
    horizon: int = setting("horizon", integer(1), "H: future actions predicted per query")
    width: int = setting("width", integer(8), "model width (study: 256)")
    layers: int = setting("layers", integer(1), "causal Transformer layers (study: 8)")
    heads: int = setting("heads", integer(1), "attention heads (study: 8)")
    dropout: float = setting("dropout", number(0, 0.9), "dropout of the Transformer layers")
    action_head: str = setting("action_head", enum("linear", "tanh"),
                               "linear output layer, or tanh (the study's failed variant)")
    gripper: str = setting("gripper", enum("regression", "bce"),
                           "regression (hard step at 0) or bce (separate classification head)")


@dataclass(frozen=True)
class Training:
    loss_weighting: str = setting("loss_weighting", enum("uniform", "time", "u_shaped", "dim_decoupled"),
                                  "loss weights over an episode's progress (docs/study.md, Ablations)")
    time_weight_warmup_epochs: int = setting("time_weight_warmup_epochs", integer(0),
                                             "'time' weighting is uniform for these first epochs (study: 100)")
    epochs: int = setting("epochs", integer(1), "training epochs (study: 500)")
    save_every: int = setting("save_every", integer(1),
                              "a checkpoint every this many epochs, and at the last (study: 50)")
    batch_size: int = setting("batch_size", integer(1), "windows per training batch")
    lr: float = setting("lr", number(0, exclusive=True), "AdamW learning rate (study: 0.0001)")
    weight_decay: float = setting("weight_decay", number(0), "AdamW weight decay")
    grad_clip: float = setting("grad_clip", number(0, exclusive=True), "gradient-norm clipping threshold")
    device: str = setting("device", enum("auto", "cpu", "cuda"),
                          "torch device of training; auto: CUDA when present, else CPU")
    joint_targets: str = setting("joint_targets", enum("absolute", "residual"),
                                 "absolute joint targets, or residual: targets minus the current joints (study: "
                                 "absolute)", "absolute")
    aux_object_weight: float = setting("aux_object_weight", number(0),
                                       "weight of an auxiliary loss predicting the object's position from the "
                                       "action token (study: 0)", 0.0)
    val_episodes: int = setting("val_episodes", integer(0),
                                "last episodes of the store held out of training; their open-loop action error is "
                                "logged every epoch (study: 0)", 0)
    lr_schedule: str = setting("lr_schedule", enum("constant", "cosine"),
                               "the learning rate over training: constant, or cosine: a linear warm-up over the "
                               "first epoch, then a cosine decay towards 0 at the end of training (study: constant)",
                               "constant")
    action_loss: str = setting("action_loss", enum("last_step", "every_step"),
                               "last_step: a window of T steps supervises its last step's H actions; every_step: "
                               "each step's action token, seeing only the steps up to its own, is supervised with "
                               "its step's H actions, and an epoch trains on the windows ending every T frames, so "
                               "each frame is still supervised once an epoch, from about 1/T of the windows "
                               "(study: last_step)", "last_step")


GROUPS = {"stores": Stores, "goal": Goal, "visual": Visual, "readout": Readout, "network": Network,
          "training": Training}
# keys of config `policy` that shape an experiment's resolution and never reach the settings
CONFIG_ONLY = {"epoch_share": {
    "schema": number(0, 1, exclusive=True),
    "doc": "share of epochs this experiment trains for, rounded (at least 1): one training budget across rows whose "
           "epochs cost differently (Table 5.7: the study's 680 / 300 / 150 epochs in 24 h for T = 5 / 20 / 40)"}}


def _fields():
    """(group, field name, config key, field) of every setting."""
    return [(g, f.name, f.metadata["key"], f) for g, cls in GROUPS.items() for f in fields(cls)]


def schema_properties() -> tuple[dict, list[str]]:
    """The JSON schema properties of config `policy` (and of each experiment's overrides), and the required keys."""
    props = {key: {**f.metadata["schema"], "description": f.metadata["doc"]} for _, _, key, f in _fields()}
    props |= {key: {**spec["schema"], "description": spec["doc"]} for key, spec in CONFIG_ONLY.items()}
    return props, [key for _, _, key, f in _fields()]


@dataclass(frozen=True)
class PolicySettings:
    stores: Stores
    goal: Goal
    visual: Visual
    readout: Readout
    network: Network
    training: Training
    name: str | None = None  # the experiment's name (config `experiments`)

    @classmethod
    def of(cls, settings: PolicySettings | dict) -> PolicySettings:
        """Settings from a resolved config dict or a checkpoint's flat dict (or settings, unchanged)."""
        if isinstance(settings, cls):
            return settings
        on = sorted(k for k, off in RETIRED.items() if k in settings and settings[k] != off)
        if on:
            raise ValueError(f"policy settings: {on} are retired levers (last in commit {RETIRED_AT}); this code "
                             "cannot run a policy trained with them on")
        settings = {k: v for k, v in settings.items() if k not in RETIRED}
        known = {key for *_, key, _ in _fields()} | {"name"}
        unknown = sorted(set(settings) - known)
        if unknown:
            raise ValueError(f"policy settings: unknown key(s) {unknown} (known: {sorted(known)})")
        missing = sorted(key for *_, key, f in _fields() if f.default is MISSING and key not in settings)
        if missing:
            raise ValueError(f"policy settings: missing key(s) {missing}")
        groups = {g: {} for g in GROUPS}
        for g, name, key, _ in _fields():
            if key in settings:
                groups[g][name] = list(settings[key]) if key == "cameras" else settings[key]
        return cls(**{g: GROUPS[g](**values) for g, values in groups.items()}, name=settings.get("name"))

    def as_dict(self) -> dict:
        """The flat dict of config keys, as checkpoints store it and the workflow's config sections hold it."""
        flat = {key: getattr(getattr(self, g), name) for g, name, key, _ in _fields()}
        return {**flat, "name": self.name}
