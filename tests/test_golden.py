"""The tiny goldens' cross-CPU comparison (tests/golden.py) on copies of the committed tables: it lets through what
float kernels decide and catches what they cannot."""

import shutil

import golden
import polars as pl
import pytest


@pytest.fixture
def results(tmp_path):
    """A results/ folder holding the committed tables and one episode file with the committed seeds."""
    shutil.copytree(golden.TINY, tmp_path / "tables", ignore=shutil.ignore_patterns(golden.SEEDS))
    (tmp_path / "runs").mkdir()
    pl.read_csv(golden.TINY / golden.SEEDS).write_parquet(tmp_path / "runs" / "all.episodes.parquet")
    return tmp_path


def edit(results, name, **columns):
    path = results / "tables" / name
    pl.read_csv(path).with_columns(**columns).write_csv(path)


def test_the_committed_copies_agree_with_themselves(results):
    assert golden.differences(results) == []


def test_what_the_policy_decides_passes(results):
    # another split between failure classes, other rates and lengths, and one more trivial episode a row
    edit(results, "table5_2.csv", **{"No Grasp": pl.col("No Grasp") - 2, "Idle": pl.col("Idle") + 1,
                                     "Total": pl.col("Total") - 1})
    edit(results, "table5_1.csv", **{"SR mean": pl.lit(0.25), "Episode length mean": pl.lit(11.5),
                                     "Trivial excluded": pl.col("Trivial excluded") + 1})
    assert golden.differences(results) == []


@pytest.mark.parametrize("name,columns,says", [
    ("table5_1.csv", {"Runs": pl.lit(3)}, "column 'Runs'"),
    ("table5_1.csv", {"Method": pl.lit("Pure Visual")}, "column 'Method'"),
    ("table5_6.csv", {"Episodes per run": pl.lit(1)}, "column 'Episodes per run'"),
    ("table5_2.csv", {"Idle": pl.col("Idle") + 1}, "the classes sum to"),
    ("table5_1.csv", {"Trivial excluded": pl.col("Trivial excluded") + 1}, "do not add up to the episodes run"),
    ("table5_2.csv", {"Extra": pl.lit(0)}, "columns"),
])
def test_a_changed_count_label_or_column_is_caught(results, name, columns, says):
    edit(results, name, **columns)
    differ = golden.differences(results)
    assert len(differ) == 1 and says in differ[0]


def test_episodes_on_other_seeds_are_caught(results):
    path = results / "runs" / "all.episodes.parquet"
    pl.read_parquet(path).with_columns(seed=pl.col("seed") + 1).write_parquet(path)
    differ = golden.differences(results)
    assert len(differ) == 1 and "episode seeds differ" in differ[0]
