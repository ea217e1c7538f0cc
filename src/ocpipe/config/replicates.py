"""How many trained policies each row of a table is: K (config `replicates`), or fewer where `table_replicates` caps
the table, so that tables whose claims need less resolution train fewer policies."""

from __future__ import annotations


def of_table(config: dict, table: str) -> int:
    cap = config["table_replicates"].get(table)
    return config["replicates"] if cap is None else min(cap, config["replicates"])
