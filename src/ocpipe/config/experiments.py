"""Named experiments: the base `policy` config with an experiment's overrides applied."""

from __future__ import annotations

from .. import paths
from .errors import ConfigError


def _with_epoch_share(policy: dict) -> dict:
    """``epoch_share`` (a fraction of the base budget) turned into the epochs the policy trains for."""
    share = policy.pop("epoch_share", 1.0)
    return {**policy, "epochs": max(1, round(policy["epochs"] * share))}


def _overridden(config: dict, name: str) -> dict:
    """Experiment ``name``'s settings before ``epoch_share`` is applied: the base policy, then its overrides."""
    experiments = config["experiments"]
    if name not in experiments:
        raise ConfigError(f"experiments.{name}: no such experiment (defined: {', '.join(sorted(experiments))})")
    return {**config["policy"], **(experiments[name] or {}), "name": name}


def resolve(config: dict, name: str) -> dict:
    """The full policy settings of experiment ``name`` (base policy, then its overrides); ``epoch_share`` is
    applied to ``epochs`` here, so a checkpoint records the epochs it was trained for."""
    return _with_epoch_share(_overridden(config, name))


def resolve_lever(config: dict, name: str) -> dict:
    """The full policy settings of lever ``name`` (config `levers.sets`): its experiment's, then its overrides,
    then ``epoch_share`` once: a lever's ``epochs`` is the base budget its experiment takes its share of, and a
    lever's own ``epoch_share`` replaces the experiment's (applied twice, shares would compound)."""
    sets = config["levers"]["sets"]
    if name not in sets:
        raise ConfigError(f"levers.sets.{name}: no such lever (defined: {', '.join(sorted(sets))})")
    lever = sets[name]
    return _with_epoch_share({**_overridden(config, lever["experiment"]), **lever.get("policy", {}), "name": name})


def saved_epochs(policy: dict) -> list[int]:
    """Epochs (1-based) whose checkpoint is kept: every save_every-th and the last."""
    epochs = list(range(policy["save_every"], policy["epochs"] + 1, policy["save_every"]))
    return epochs if epochs and epochs[-1] == policy["epochs"] else [*epochs, policy["epochs"]]


def features_store(policy: dict) -> str:
    return f"{policy['task']}_{policy['cams']}_{policy['resolution']}_{policy['encoder']}"


def frames_store(policy: dict) -> str:
    return f"{policy['task']}_{policy['cams']}_{policy['resolution']}"


def problems(policy: dict) -> list[str]:
    """Combinations the schema cannot express, named by key."""
    key = f"experiments.{policy['name']}" if "name" in policy else "policy"
    out = []
    if policy["fusion"] == "cross_attention" and (len(policy["cameras"]) != 2 or policy["visual_head"] != "tokens"):
        out.append(f"  {key}.fusion: cross_attention needs two cameras and visual_head 'tokens'")
    if policy["heads"] and policy["width"] % policy["heads"]:
        out.append(f"  {key}.heads: width {policy['width']} is not divisible by {policy['heads']} heads")
    if max(policy["cameras"]) > 1:
        out.append(f"  {key}.cameras: a frames store has two cameras (indices 0 and 1)")
    if policy["goal"] == "2d" and policy["cams"] == "native" and policy["goal_calibration"] == "approx":
        out.append(f"  {key}.goal_calibration: the hand camera moves, so 'approx' 2d goals exist only for cams 'dual'")
    if policy["encoder"] == "state":
        if policy["goal"] == "2d":
            out.append(f"  {key}.goal: the 'state' control renders no camera, so it takes goal 'none' or '3d'")
        if list(policy["cameras"]) != [0]:
            out.append(f"  {key}.cameras: the 'state' control has one token stream: cameras [0]")
    if policy.get("readout_scenes"):
        if not policy.get("object_readout"):
            out.append(f"  {key}.readout_scenes: fits the object read-out, so it needs object_readout: true")
        if policy["encoder"] == "state":
            out.append(f"  {key}.readout_scenes: needs an image encoder (the control has no read-out to fit)")
    if policy.get("visual_head") == "none" and not policy.get("object_readout"):
        out.append(f"  {key}.visual_head: 'none' leaves the policy only the object read-out's token, so it needs "
                   "object_readout: true (or visual_head: tokens)")
    return out


# the user-given weight files each pretrained encoder loads (keys under config `encoders`), any one of them enough
WEIGHT_KEYS = {"spot": ("spot.checkpoint", "spot.dino_checkpoint"), "dino_cls": ("dino.checkpoint",),
               "dino_grid4": ("dino.checkpoint",), "dino_dense": ("dino.checkpoint",)}
WEIGHT_FILES = {"spot.checkpoint": "SPOT checkpoint.pt.tar", "spot.dino_checkpoint": "dino_vitbase16_pretrain.pth",
                "dino.checkpoint": "dino_vitbase16_pretrain.pth"}


def _weight(config: dict, key: str) -> str | None:
    section, name = key.split(".")
    return config["encoders"][section][name] or None


def missing_weights(config: dict, policy: dict) -> str | None:
    """Why an experiment cannot run offline (its encoder needs weight files config does not give), or None.

    Tables show this in the experiment's row instead of failing the whole target."""
    keys = WEIGHT_KEYS.get(policy["encoder"], ())
    if keys and not any(_weight(config, k) for k in keys):
        return "needs weights: set " + " or ".join(f"encoders.{k} ({WEIGHT_FILES[k]})" for k in keys)
    return None


def encoder_checkpoint(config: dict, encoder: str) -> str | list:
    """The checkpoint file a features job of ``encoder`` depends on: a workflow output, a user-given weight file,
    or none ([]: the privileged-state control reads poses from the frames store; a missing weight file's job
    fails with a message naming the key)."""
    if encoder == "slots_ssl":
        return f"{paths.SLOTS_SSL}/model.pt"
    if encoder == "spot" and not _weight(config, "spot.checkpoint") and _weight(config, "spot.dino_checkpoint"):
        return f"{paths.SPOT_SLOTS}/slot_module.pt"  # slots trained on the given DINO weights
    keys = WEIGHT_KEYS.get(encoder, ())
    return _weight(config, keys[0]) if keys and _weight(config, keys[0]) else []
