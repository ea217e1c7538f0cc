"""Like for like: what a table's rows may differ in, and where a profile's recipe departs from the study's.

The study compared policies "identical except for" the variable each table studies. ``unlike_rows`` names every
setting in which two rows of a table differ beyond that variable (the registry's ``varies``, plus the settings a
named row may differ in, with the study's reason: the privileged-state control, dense DINO). ``footer`` is the
line under every table: the profile, what the study held fixed and varied, and where this profile's recipe
departs from the study's, the same for every row (or said per row where it is not)."""

from __future__ import annotations

from functools import cache

import yaml

from ..config import replicates
from ..config.experiments import resolve
from ..config.validate import REPO_ROOT
from .registry import EVERY_TABLE_HOLDS, TABLES

# The study's recipe is config/thesis.yaml's (the full profile): its policy and evaluation settings, less the sizes
# the default profile shrinks by design, and its demo count
STUDY_PROFILE = REPO_ROOT / "config" / "thesis.yaml"
SIZES = {"policy": ("epochs", "save_every", "time_weight_warmup_epochs", "val_episodes"),
         "evaluation": ("seed_pool_size", "sweep_episodes", "stability_runs", "stability_episodes",
                        "failure_episodes", "training_time_episodes")}
# settings that only mean something with the object read-out on: named only where it is
READOUT_DETAILS = ("readout_standardize", "readout_yaw_weight")


@cache
def study_recipe() -> tuple[dict, dict, int]:
    """(policy settings, evaluation settings, demos) of the study, in the order the footer names them."""
    profile = yaml.safe_load(STUDY_PROFILE.read_text())
    policy, evaluation = ({k: v for k, v in profile[s].items() if k not in SIZES[s] and k not in READOUT_DETAILS}
                          for s in ("policy", "evaluation"))
    return policy, evaluation, profile["demos"]["num_demos"]


IGNORED = {"name", "device"}  # where a row runs is not what it is


def row_settings(config: dict, table: str) -> dict[str, dict]:
    """Row label -> the experiment's resolved policy settings."""
    return {label: resolve(config, exp) for label, exp in config["tables"][table].items()}


def unlike_rows(config: dict, table: str) -> list[str]:
    """Every setting two rows of ``table`` differ in that the study did not vary there, as 'label vs label: key'."""
    spec, rows = TABLES[table], config["tables"][table]
    settings = row_settings(config, table)
    labels = list(settings)
    out = []
    for i, a in enumerate(labels):
        for b in labels[i + 1:]:
            free = set(spec.varies) | IGNORED
            free |= set(spec.allowed.get(rows[a], ())) | set(spec.allowed.get(rows[b], ()))
            keys = sorted(k for k in settings[a].keys() | settings[b].keys()
                          if k not in free and settings[a].get(k) != settings[b].get(k))
            out += [f"{table}: {a!r} vs {b!r}: {k} {settings[a].get(k)!r} vs {settings[b].get(k)!r}" for k in keys]
    return out


def barred(config: dict, table: str) -> list[str]:
    """Every row of ``table`` that departs where the study's variable would be reached around (the registry's
    ``holds`` and EVERY_TABLE_HOLDS), as 'table row (experiment): key value, must be value'."""
    holds = {**EVERY_TABLE_HOLDS, **TABLES[table].holds}
    out = []
    for (label, settings), exp in zip(row_settings(config, table).items(), config["tables"][table].values(),
                                      strict=True):
        out += [f"tables.{table}: row {label!r} (experiment {exp!r}) has {key} {settings.get(key)!r}, which must be "
                f"{want!r} in this table (docs/study.md, how each table's variable reaches its rows)"
                for key, want in holds.items() if settings.get(key) != want]
    return out


def departures(config: dict, table: str) -> list[str]:
    """Where the rows' recipe departs from the study's: 'key value' when every row agrees, else per row."""
    settings = row_settings(config, table)
    out = []
    study_policy, study_evaluation, study_demos = study_recipe()
    for key, study in study_policy.items():
        values = {label: s[key] for label, s in settings.items() if key in s}
        off = {label: v for label, v in values.items() if v != study}
        if not off:
            continue
        shown = {repr(v): v for v in off.values()}
        if len(shown) > 1:
            out.append(f"{key} " + ", ".join(f"{v} ({label})" for label, v in off.items()))
        else:
            others = [label for label in values if label not in off]
            named = ("" if not others else f" ({', '.join(off)} only)" if len(off) < len(others)
                     else f" (not {', '.join(others)})")  # whichever list is shorter
            out.append(f"{key} {next(iter(shown.values()))}{named}")
        if key == "object_readout":
            agreed = [k for k in READOUT_DETAILS if len({repr(s.get(k)) for s in settings.values()}) == 1]
            out += [f"{k} {next(iter(settings.values()))[k]}" for k in agreed]
    ev = config["evaluation"]
    out += [f"evaluation.{k} {ev[k]}" for k, v in study_evaluation.items() if ev.get(k, v) != v]
    demos = config.get("demos", {}).get("num_demos", study_demos)
    return out + ([f"demos.num_demos {demos}"] if demos != study_demos else [])


def footer(config: dict, table: str) -> str:
    """The line under a table: profile, what its rows vary, what the study held fixed, this profile's departures."""
    spec = TABLES[table]
    varies = ", ".join(spec.varies) or "nothing (one row)"
    dep = departures(config, table)
    return (f"Profile {config.get('profile', '?')}. Rows differ only in: {varies}"
            + (f" (and {', '.join(spec.allowed)} in what it needs to run)" if spec.allowed else "")
            + (f"; the study held fixed: {spec.fixed}" if spec.fixed else "") + ". "
            + (f"Each row: {k} trained policies. " if (k := replicates.of_table(config, table)) > 1 else
               "Each row: one trained policy. ")
            + ("Departures from the study's recipe, the same for every row unless named: " + "; ".join(dep)
               if dep else "No departure from the study's recipe") + ".")
