"""One experiment's policy settings, typed: config `policy` with the experiment's overrides (config/README.md lists
each key with its allowed values; the schema validates them before anything runs).

Checkpoints store the settings as a plain dict (readable without this module); ``PolicySettings.of`` turns a dict
back into settings, filling the keys added after a checkpoint was written with the values that reproduce how it
was trained (the study's recipe)."""

from __future__ import annotations

from dataclasses import MISSING, asdict, dataclass, fields

# Levers that were measured, lost and were removed, with the value that means "off" (the study's) and the last
# commit that had them (docs/measurements.md has their figures). A checkpoint that names one at that value loads;
# one trained with it on cannot be rebuilt by this code.
RETIRED = {"slot_geometry": False, "proprio_noise": 0.0, "lr_schedule": "constant", "first_frame": False,
           "readout_noise": 0.0, "readout_tcp_relative": False}
RETIRED_AT = "19a73bd"


@dataclass(frozen=True)
class PolicySettings:
    # what the policy sees
    task: str  # ManiSkill task: PickCube-v1 | StackCube-v1
    cams: str  # camera set of its frames store: dual (base + side) | native (base + hand)
    resolution: int  # square image size of the frames store, pixels
    encoder: str  # frozen encoder whose tokens it reads: slots_ssl | spot | dino_cls | dino_grid4 | dino_dense | state
    cameras: list[int]  # which cameras of the store (0: base, 1: side or hand)
    goal: str  # none (pure visual) | 2d (the goal projected into each camera) | 3d (the goal's xyz)
    goal_calibration: str  # the 2d goal from the simulator's cameras (exact) or a hand-measured model (approx)
    proprio: str  # joints7 | qpos9_global | qpos9_grouped | joints7_tcp
    window: int  # T: past timesteps in each query
    horizon: int  # H: future actions predicted per query
    # the network
    width: int  # token width
    layers: int  # transformer decoder layers
    heads: int  # attention heads
    dropout: float
    fusion: str  # concat | cross_attention (between the two cameras' tokens)
    visual_head: str  # tokens | flatten | deepsets | weighted_pool | slot_transformer | none (read-out only)
    action_head: str  # linear | tanh
    gripper: str  # regression | bce
    # training
    loss_weighting: str  # uniform | time | u_shaped | dim_decoupled (by episode progress)
    time_weight_warmup_epochs: int  # 'time' weighting is uniform for these first epochs
    epochs: int
    save_every: int  # a checkpoint every this many epochs, and at the last
    batch_size: int
    lr: float  # AdamW learning rate
    weight_decay: float
    grad_clip: float  # gradient-norm clipping threshold
    device: str  # auto | cpu | cuda
    # departures from the study's recipe (config/thesis.yaml switches each off)
    token_norm: str = "none"  # none | zscore: standardize the visual token dimensions
    aux_object_weight: float = 0.0  # weight of the auxiliary loss predicting the object's position
    joint_targets: str = "absolute"  # absolute | residual (targets minus the current joints)
    object_readout: bool = False  # a token per step: the object's pose read off the frozen tokens
    readout_scenes: bool = False  # fit that read-out first on the demo frames plus extra scenes, then freeze it
    readout_standardize: str = "token_dims"  # token_dims | element: how the read-out's input is standardized
    readout_yaw_weight: float = 1.0  # weight of the yaw terms in the read-out's loss (position's: 1)
    goal_norm: str = "none"  # none | zscore: standardize the goal input with training-set statistics
    goal_relative: str = "none"  # none | tcp: the goal input also holds the goal minus the TCP (in the goal's frame)
    visual_dropout: float = 0.0  # chance that a training step's visual tokens are blanked (the read-out stays)
    val_episodes: int = 0  # last demos held out of training for the open-loop error
    name: str | None = None  # the experiment's name (config `experiments`)

    @classmethod
    def of(cls, settings: PolicySettings | dict) -> PolicySettings:
        """Settings from a resolved config dict or a checkpoint's dict (or settings, unchanged)."""
        if isinstance(settings, cls):
            return settings
        known = {f.name for f in fields(cls)}
        on = sorted(k for k, off in RETIRED.items() if k in settings and settings[k] != off)
        if on:
            raise ValueError(f"policy settings: {on} are retired levers (last in commit {RETIRED_AT}); this code "
                             "cannot run a policy trained with them on")
        settings = {k: v for k, v in settings.items() if k not in RETIRED}
        unknown = sorted(set(settings) - known)
        if unknown:
            raise ValueError(f"policy settings: unknown key(s) {unknown} (known: {sorted(known)})")
        missing = sorted(f.name for f in fields(cls) if f.default is MISSING and f.name not in settings)
        if missing:
            raise ValueError(f"policy settings: missing key(s) {missing}")
        values = dict(settings)
        values["cameras"] = list(values["cameras"])
        return cls(**values)

    def as_dict(self) -> dict:
        """A plain dict, as checkpoints store it and the workflow's config sections hold it."""
        return asdict(self)
