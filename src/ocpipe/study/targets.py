"""The study's tables and figures as targets: what each reads per row, and where those files live.

A table row is an experiment (config `tables`: table -> row label -> experiment), trained as K policies (config
`replicates`, from `replicate_seed_offset`); a table capped by `table_replicates` reads the first of them only, the
same number for each of its rows. Each table reads a fixed set of per-policy inputs (`inputs`); the
workflow asks for exactly those files, and rows whose encoder needs weight files the config does not give are
reported as such instead of being built."""

from __future__ import annotations

from .. import paths
from ..config import replicates
from ..config.experiments import features_store, missing_weights, resolve
from .findings import BY_ID, SCOPES
from .inputs import Input
from .registry import TABLES


def policies(config: dict, exp: str, table: str | None = None) -> list[str]:
    """The ids (paths.policy_id) of the policies behind experiment ``exp``: its rows' in ``table``, or, without a
    table, those of every table it is a row of (the most any of them reads; K where none)."""
    tables = [table] if table else [t for t, r in config["tables"].items() if exp in r.values()]
    k = max((replicates.of_table(config, t) for t in tables), default=config["replicates"])
    first = config["replicate_seed_offset"]
    return [paths.policy_id(exp, i) for i in range(first, first + k)]


def rows(config: dict, table: str) -> dict[str, str]:
    if table not in config["tables"]:
        raise KeyError(f"tables.{table}: not in the config (defined: {', '.join(config['tables'])})")
    return dict(config["tables"][table])


def unavailable(config: dict, table: str) -> dict[str, str]:
    """Row label -> why it cannot run with this config (e.g. weights not given)."""
    out = {}
    for label, exp in rows(config, table).items():
        reason = missing_weights(config, resolve(config, exp))
        if reason:
            out[label] = reason
    return out


def inputs(config: dict, table: str, needs: tuple[Input, ...] | None = None) -> list[str]:
    """Every file a table (or a figure drawing its rows) reads, for the rows that can run."""
    skip = unavailable(config, table)
    needs = TABLES[table].needs if needs is None else needs
    return [f for label, exp in rows(config, table).items() if label not in skip
            for pid in policies(config, exp, table) for need in needs for f in need.files(config, pid)]


def experiments_of(config: dict, tables=None) -> list[str]:
    """Experiments that the named tables (all by default) need built, in first-use order."""
    out = []
    for table in tables or config["tables"]:
        skip = unavailable(config, table)
        out += [e for label, e in rows(config, table).items() if label not in skip and e not in out]
    return out


def findings_inputs(config: dict, scope: str) -> list[str]:
    """Every episode file the findings of ``scope`` read, for the rows that can run."""
    out = []
    for fid in SCOPES[scope]:
        f = BY_ID[fid]
        out += [p for p in inputs(config, f.table, f.needs) if p not in out]
    return out


def image_stores(config: dict, table: str) -> list[str]:
    """The features stores of a table's rows that read images (not the privileged-state control), in row order."""
    skip = unavailable(config, table)
    settings = [resolve(config, exp) for label, exp in rows(config, table).items() if label not in skip]
    return list(dict.fromkeys(features_store(s) for s in settings if s["encoder"] != "state"))
