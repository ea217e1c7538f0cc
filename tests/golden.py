"""What of the tiny run is the same on any x86-64 CPU, compared against tests/expected/tiny/.

A 2-epoch policy's outputs follow the CPU's float kernels (vector width, FMA, thread split): which side of its
threshold the gripper ends on split Pure Visual's four never-grasping episodes 4/0, 3/1 and 2/2 between No Grasp and
Idle on three machines. So success rates and failure shares are compared byte for byte only between two runs on one
machine (tests/test_workflow.py's rerun test); against the committed tables, only what no float kernel decides: each
table's columns in order, its rows' labels, its runs and episodes per run, that the failure classes partition each
row's judged episodes and those with the trivial ones make up every episode run, and which episode seeds every
evaluation met. (How many episodes are trivial, a success within the first steps, follows the policy, so only
their sum with the judged ones is compared.) `python tests/golden.py RESULTS` writes
the committed copies from a tiny run's results/ (when a change is meant to alter them).
"""

from __future__ import annotations

import sys
from pathlib import Path

import polars as pl

TINY = Path(__file__).parent / "expected" / "tiny"
TABLES = ("table5_1.csv", "table5_2.csv", "table5_6.csv")
# columns no float kernel decides: labels, configuration and the episodes run
STABLE_COLUMNS = ("Method", "Fusion", "Episodes per run", "Runs", "Policies")
FAILURE_CLASSES = ("Success", "Near Miss", "Drop", "No Grasp", "Idle", "Unknown")
SEEDS = "episode_seeds.csv"


def episode_seeds(results: Path) -> pl.DataFrame:
    """Every evaluated episode's (experiment, kind, run, seed pool, seed), sorted: set by config alone."""
    files = sorted(results.glob("**/*.episodes.parquet"))
    if not files:
        raise FileNotFoundError(f"no episode files under {results}")
    keys = ["exp", "kind", "run", "seed_pool", "seed"]
    return pl.concat([pl.read_parquet(f, columns=keys) for f in files]).sort(keys)


def table_differences(got: pl.DataFrame, want: pl.DataFrame, name: str) -> list[str]:
    """Where a tiny run's table differs from the committed one in anything that holds on every CPU."""
    if got.columns != want.columns:
        return [f"{name}: columns {got.columns} != {want.columns}"]
    out = [f"{name}: column {c!r} {got[c].to_list()} != {want[c].to_list()}"
           for c in STABLE_COLUMNS if c in want.columns and got[c].to_list() != want[c].to_list()]
    if "Total" in got.columns:  # the failure classes partition each row's episodes
        summed = got.select(pl.sum_horizontal(*FAILURE_CLASSES))[:, 0]
        if summed.to_list() != got["Total"].to_list():
            out.append(f"{name}: the classes sum to {summed.to_list()}, not the Total {got['Total'].to_list()}")
    return out


def differences(results: Path, expected: Path = TINY) -> list[str]:
    """Everything that differs between a tiny run's results/ and the committed copies, on any CPU."""
    names = sorted(p.name for p in expected.glob("*.csv") if p.name != SEEDS)
    if tuple(names) != TABLES:
        return [f"{expected} holds {names}, not {list(TABLES)}"]
    got = {name: pl.read_csv(results / "tables" / name) for name in names}
    out = []
    for name in names:
        out += table_differences(got[name], pl.read_csv(expected / name), name)
    # the same rows; with the tiny profile's failure_episodes: 0, Table 5.2 classifies the stability runs, so its
    # judged episodes and Table 5.1's trivial ones are every episode run
    t1, t2 = got["table5_1.csv"], got["table5_2.csv"]
    policies = t1["Policies"] if "Policies" in t1.columns else 1
    run = (t1["Runs"] * t1["Episodes per run"] * policies).to_list()
    if not out and (t2["Total"] + t1["Trivial excluded"]).to_list() != run:
        out.append(f"Table 5.2's totals {t2['Total'].to_list()} and Table 5.1's trivial episodes "
                   f"{t1['Trivial excluded'].to_list()} do not add up to the episodes run")
    seeds, want = episode_seeds(results), pl.read_csv(expected / SEEDS)
    if not seeds.equals(want):  # exact: integer seeds and their labels
        extra, missing = (a.join(b, on=a.columns, how="anti") for a, b in ((seeds, want), (want, seeds)))
        out.append(f"the episode seeds differ from {SEEDS}: met, not expected\n{extra}\nexpected, not met\n{missing}")
    return out


if __name__ == "__main__":
    results = Path(sys.argv[1])
    for name in TABLES:
        (TINY / name).write_text((results / "tables" / name).read_text())
    episode_seeds(results).write_csv(TINY / SEEDS)
    print(f"wrote {', '.join(TABLES)} and {SEEDS} to {TINY}")
