"""Loading and validating the pipeline configuration (one YAML profile plus optional overrides)."""

from __future__ import annotations

import copy
import difflib
from pathlib import Path

import jsonschema
import yaml

from ..policy.settings import schema_properties
from .errors import ConfigError
from .experiments import problems as policy_problems
from .experiments import resolve, resolve_lever
from .seed_pools import policies_drawn, pool_problems

# evaluation settings that measure something other than the policy: never behind a table
DIAGNOSTIC_FILTERS = ("true_pose",)

REPO_ROOT = Path(__file__).resolve().parents[3]
SCHEMA_PATH = REPO_ROOT / "workflow" / "schemas" / "config.schema.yaml"


def deep_merge(base: dict, override: dict) -> dict:
    """Recursively merge ``override`` into a copy of ``base`` (the way Snakemake merges --configfile)."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def load(*paths: str | Path, schema_path: str | Path = SCHEMA_PATH) -> dict:
    """Load one or more YAML files (later ones override earlier ones) and validate the result."""
    config: dict = {}
    for path in paths:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"config file not found: {path}")
        with path.open() as fh:
            config = deep_merge(config, yaml.safe_load(fh) or {})
    validate(config, schema_path)
    return config


def _key_path(error: jsonschema.ValidationError) -> str:
    return ".".join(str(p) for p in error.absolute_path) or "<top level>"


def _allowed(error: jsonschema.ValidationError) -> str:
    schema = error.schema if isinstance(error.schema, dict) else {}
    if "enum" in schema:
        return "one of " + ", ".join(repr(v) for v in schema["enum"])
    if "const" in schema:
        return f"exactly {schema['const']!r}"
    parts = []
    if "type" in schema:
        parts.append(str(schema["type"]))
    for word, sym in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="), ("exclusiveMaximum", "<")):
        if word in schema:
            parts.append(f"{sym} {schema[word]}")
    return " ".join(parts)


def _unknown_keys(error: jsonschema.ValidationError) -> list[str]:
    """One line per key the schema does not know, with the nearest known key and the full list."""
    known = sorted((error.schema or {}).get("properties", {}))
    prefix = _key_path(error) + "." if error.absolute_path else ""
    out = []
    for key in sorted(set(error.instance) - set(known), key=str):
        near = difflib.get_close_matches(str(key), known, n=1)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        out.append(f"  {prefix}{key}: unknown key{hint} (allowed keys: {', '.join(repr(k) for k in known)})")
    return out


def load_schema(schema_path: str | Path = SCHEMA_PATH) -> dict:
    """The config schema: the file, with the policy keys (config `policy` and each experiment's overrides) filled
    in from their declarations in ocpipe.policy.settings."""
    with Path(schema_path).open() as fh:
        schema = yaml.safe_load(fh)
    props, required = schema_properties()
    top = schema["properties"]
    top["policy"] |= {"properties": props, "required": required}
    top["experiments"]["additionalProperties"]["properties"] = props
    top["levers"]["properties"]["sets"]["additionalProperties"]["properties"]["policy"]["properties"] = props
    return schema


def validate(config: dict, schema_path: str | Path = SCHEMA_PATH) -> None:
    """Raise ConfigError naming every offending key, what it holds and what is allowed."""
    schema = load_schema(schema_path)
    validator = jsonschema.Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: list(map(str, e.absolute_path)))
    problems = []
    for err in errors:
        if err.validator == "additionalProperties" and err.validator_value is False:
            problems.extend(_unknown_keys(err))
            continue
        # Report the most specific sub-error of a oneOf/anyOf failure rather than the umbrella message.
        leaf = min(err.context, key=lambda e: len(e.schema_path)) if err.context else err
        allowed = _allowed(leaf)
        problems.append(f"  {_key_path(err)}: {leaf.message}" + (f" (allowed: {allowed})" if allowed else ""))
    problems.extend(_cross_field_problems(config) if not problems else [])
    if problems:
        raise ConfigError("invalid configuration:\n" + "\n".join(problems))


def demo_seed_range(config: dict) -> range:
    """Every seed the demo generator may try: disjoint per-shard ranges, consecutive from demos.seed_start."""
    d = config["demos"]
    return range(d["seed_start"], d["seed_start"] + d["num_demos"] * d["attempts_per_demo"])


def scene_seed_problems(config: dict) -> list[str]:
    """Scene seeds (config `scenes`) must clear the demo seeds (the read-out would see demo scenes twice) and the
    evaluation pool (it would have seen the held-out episodes' first frames)."""
    start = config["scenes"]["seed_start"]
    scenes = range(start, start + config["scenes"]["count"])
    pool_start = config["evaluation"]["seed_pool_start"]
    pools = {"the demo seeds": demo_seed_range(config),
             "the evaluation pool": range(pool_start, pool_start + config["evaluation"]["seed_pool_size"])}
    return [f"  scenes.seed_start: scene seeds {scenes.start}..{scenes.stop - 1} overlap {what} "
            f"{pool.start}..{pool.stop - 1}; move scenes.seed_start past both"
            for what, pool in pools.items() if scenes.start < pool.stop and pool.start < scenes.stop]


def _cross_field_problems(config: dict) -> list[str]:
    problems = []
    seeds = demo_seed_range(config)
    pool_start = config["evaluation"]["seed_pool_start"]
    pool = range(pool_start, pool_start + config["evaluation"]["seed_pool_size"])
    if seeds.start < pool.stop and pool.start < seeds.stop:
        problems.append(
            f"  demos.seed_start: demo seeds {seeds.start}..{seeds.stop - 1} (num_demos x attempts_per_demo) "
            f"overlap the held-out evaluation pool {pool.start}..{pool.stop - 1} (evaluation.seed_pool_start); "
            "move one of them"
        )
    if config["demos"]["shards"] > config["demos"]["num_demos"]:
        problems.append(
            f"  demos.shards: {config['demos']['shards']} shards for {config['demos']['num_demos']} demos; "
            "use at most one shard per demo"
        )
    if config["cameras"]["near"] >= config["cameras"]["far"]:
        problems.append("  cameras.near: must be smaller than cameras.far")
    if config["demos"]["source"] == "import":
        for task in config["tasks"]:
            paths = config["demos"].get("import", {}).get(task, {})
            for kind in ("h5", "json"):
                if not paths.get(kind):
                    problems.append(f"  demos.import.{task}.{kind}: required when demos.source is 'import'")
    for table, rows in config["tables"].items():
        for label, exp in rows.items():
            if exp not in config["experiments"]:
                problems.append(f"  tables.{table}.{label}: experiment {exp!r} is not defined under experiments")
    problems += [f"  table_replicates.{table}: no such table under tables (defined: {', '.join(config['tables'])})"
                 for table in config["table_replicates"] if table not in config["tables"]]
    problems += pool_problems(config["evaluation"], policies_drawn(config))
    if config["evaluation"]["readout_filter"] in DIAGNOSTIC_FILTERS:
        problems.append(f"  evaluation.readout_filter: {config['evaluation']['readout_filter']!r} is a diagnostic "
                        "(perfect perception), not a method: the tables and levers refuse it")
    problems += scene_seed_problems(config)
    problems += policy_problems(config["policy"])
    for name in config["experiments"]:
        problems += [p for p in policy_problems(resolve(config, name)) if p not in problems]
    return problems + lever_problems(config)


def lever_problems(config: dict) -> list[str]:
    """A lever names a defined experiment, resolves to valid settings and asks for no more validation episodes than
    the validation pool holds."""
    levers = config["levers"]
    problems = []
    pool = config["evaluation"]["validation_pool_size"]
    if levers["sets"] and levers["episodes"] > pool:
        problems.append(f"  levers.episodes: {levers['episodes']} episodes per lever, but the validation pool holds "
                        f"{pool} seeds (evaluation.validation_pool_size)")
    for name in levers.get("build") or []:
        if name not in levers["sets"]:
            problems.append(f"  levers.build: {name!r} is not a lever under levers.sets "
                            f"(defined: {', '.join(sorted(levers['sets']))})")
    for name, lever in levers["sets"].items():
        if lever["experiment"] not in config["experiments"]:
            problems.append(f"  levers.sets.{name}.experiment: {lever['experiment']!r} is not defined under "
                            "experiments")
            continue
        problems += [p.replace(f"experiments.{name}", f"levers.sets.{name}.policy")
                     for p in policy_problems(resolve_lever(config, name))]
    return problems
