"""K trained policies per table row: their ids and folders, their seeds, the tables' spread over policies and the
findings' tests with the policy as the unit (synthetic episode files whose verdicts are known)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from synthetic_runs import classes, write_rows

from ocpipe import paths
from ocpipe.config import replicates
from ocpipe.config.errors import ConfigError
from ocpipe.config.seed_pools import pool_problems
from ocpipe.config.validate import validate
from ocpipe.evaluation.jobs import seeds_for
from ocpipe.study import conditions, inputs, report, targets

REPO = Path(__file__).resolve().parents[1]


def test_policy_ids_keep_policy_0_in_the_experiments_folder_and_split_back():
    assert [paths.policy_id("goal2d", k) for k in range(3)] == ["goal2d", "goal2d@1", "goal2d@2"]
    assert [paths.split_policy(p) for p in ("goal2d", "goal2d@1", "goal2d@12")] == [
        ("goal2d", 0), ("goal2d", 1), ("goal2d", 12)]
    for bad in ("goal2d@0", "goal2d@x", "goal2d@01", "goal2d@"):
        with pytest.raises(ValueError, match="experiment@k"):
            paths.split_policy(bad)


def test_a_build_names_its_policies_from_the_offset(default_config):
    assert targets.policies(default_config, "goal2d") == ["goal2d", "goal2d@1", "goal2d@2", "goal2d@3", "goal2d@4"]
    second = {**default_config, "replicate_seed_offset": 5}
    assert targets.policies(second, "goal2d") == [f"goal2d@{k}" for k in range(5, 10)]


def test_a_capped_table_reads_each_rows_first_policies_and_trains_no_more(default_config):
    capped = {**default_config, "table_replicates": {"table5_3": 3, "table5_7": 3, "table5_9": 7}}
    # goal2d is a row of 5.1 (K = 5) and of 5.3 (capped): 5.3 reads its first 3, like its other rows
    assert targets.policies(capped, "goal2d", "table5_3") == ["goal2d", "goal2d@1", "goal2d@2"]
    assert targets.policies(capped, "goal2d") == targets.policies(capped, "goal2d", "table5_1")
    assert len(targets.policies(capped, "goal2d", "table5_1")) == 5
    assert replicates.of_table(capped, "table5_9") == 5  # a cap above K leaves K
    # an experiment only capped tables read trains only as many policies as they read
    assert targets.policies(capped, "window40") == ["window40", "window40@1", "window40@2"]
    files = targets.inputs(capped, "table5_3")
    assert "results/runs/goal2d_exact_224@2/stability/run_0.episodes.parquet" in files
    assert not [f for f in files if "@3/" in f or "@4/" in f]
    every = [f for t in capped["tables"] for f in targets.inputs(capped, t)]
    assert not [f for f in every if f.startswith(("results/runs/window40@3/", "results/runs/goal2d_exact@3/"))]
    assert "results/runs/goal2d@4/stability/run_0.episodes.parquet" in every


def test_the_line_under_a_table_and_the_findings_note_say_how_many_policies_a_row_is(default_config, tmp_path):
    capped = {**default_config, "table_replicates": {"table5_3": 3}}
    assert "Each row: 3 trained policies." in conditions.footer(capped, "table5_3")
    assert "Each row: 5 trained policies." in conditions.footer(capped, "table5_1")
    note = report._tests_note(capped, "findings")
    assert "5 (Table 5.1, Table 5.2, Table 5.4" in note and "3 (Table 5.3)" in note
    one = {**default_config, "replicates": 1}
    assert conditions.footer(one, "table5_1").count("Each row: one trained policy.") == 1
    assert report._tests_note(one, "findings_main").startswith("One policy per row")


def test_a_cap_on_a_table_the_config_lacks_is_named(default_config):
    bad = {**default_config, "table_replicates": {"table5_33": 3}}
    with pytest.raises(ConfigError, match=r"table_replicates\.table5_33: no such table under tables"):
        validate(bad)


def test_each_policy_meets_its_own_blocks_the_same_for_every_row_and_policy_0_keeps_its_seeds(default_config):
    ev = default_config["evaluation"]
    one = {**ev, "stability_runs": 3}
    # policy 0's blocks do not move when more policies are drawn: a one-policy build keeps the seeds it always had
    assert seeds_for("stability", one, 0, run=2) == seeds_for("stability", one, 0, run=2, replicate=0)
    blocks = [seeds_for("sweep", ev, 0)]
    for k in range(10):
        blocks += [seeds_for("stability", ev, 0, replicate=k), seeds_for("training_time", ev, 0, replicate=k)]
    flat = [s for b in blocks for s in b]
    assert len(flat) == len(set(flat)) == 6 + 10 * (40 + 30)  # pairwise disjoint
    assert min(flat) >= ev["seed_pool_start"] + ev["validation_pool_size"]  # all from the test pool
    assert seeds_for("sweep", ev, 0) == seeds_for("sweep", ev, 0, replicate=7)  # one sweep block for all


def test_a_pool_too_small_for_the_policies_names_the_keys(default_config):
    problems = pool_problems(default_config["evaluation"], 12)
    assert problems and "seed_pool_size" in problems[0] and "replicates" in problems[0]
    assert not pool_problems(default_config["evaluation"], 10)


def _spread(base: int, offsets, steps: int, cls) -> list:
    """Five policies' specs: one 40-episode run each, with ``base`` + offset successes."""
    return [([base + d], steps, cls) for d in offsets]


def test_tables_give_the_spread_over_policies_beside_one_policys_episode_noise(default_config, tmp_path):
    runs = tmp_path / "runs"
    succ = [8, 12, 16, 20, 24]
    write_rows(default_config, runs, {
        "pure_visual": _spread(0, succ, 140, classes(near_miss=20, no_grasp=5, success=10, n=40)),
        "goal2d": _spread(10, succ, 110, classes(near_miss=10, no_grasp=5, success=20, n=40)),
        "goal3d": _spread(14, succ, 80, classes(near_miss=2, no_grasp=5, success=30, n=40)),
        "state_control": _spread(15, succ, 70, classes(near_miss=1, no_grasp=0, success=39, n=40)),
    })
    t = report.write_table(default_config, "table5_1", tmp_path / "t.csv", tmp_path / "t.md", str(runs))
    row = t.row(0, named=True)
    rates = np.array(succ) / 40
    assert row["Policies"] == 5 and row["Runs"] == 1 and row["Episodes per run"] == 40
    # derived: five float64 rates, numpy's mean and std in one process against the same formulas: a few ulps
    assert row["SR mean"] == pytest.approx(rates.mean(), rel=1e-12)
    assert row["SR std over policies"] == pytest.approx(rates.std(ddof=1), rel=1e-12)  # derived: as above
    half = 2.7764451051977987 * rates.std(ddof=1) / np.sqrt(5)  # t(0.975, 4)
    # derived: the t quantile to 16 digits and a few float64 operations: far below 1e-9 relative
    assert (row["SR 95 % high"] - row["SR 95 % low"]) / 2 == pytest.approx(half, rel=1e-9)
    noise = np.sqrt(np.mean(rates * (1 - rates) / 40))
    assert row["SR episode std (one policy)"] == pytest.approx(noise, rel=1e-12)  # derived: as above
    t2 = report.write_table(default_config, "table5_2", tmp_path / "t2.csv", tmp_path / "t2.md", str(runs))
    # every failure share pooled over all the row's episodes: 5 policies x 20 Near Miss of 40
    assert t2.row(0, named=True)["Near Miss"] == 100 and t2.row(0, named=True)["Total"] == 200


def findings_of(config, tmp_path, rows, scope="findings_main"):
    runs = tmp_path / "runs"
    write_rows(config, runs, rows)
    frame = report.write_findings(config, scope, tmp_path / "f.csv", tmp_path / "f.md", str(runs))
    return {r["Finding"]: r for r in frame.iter_rows(named=True)}


def test_the_study_reproduced_across_policies_with_the_equivalence_shown(default_config, tmp_path):
    got = findings_of(default_config, tmp_path, {
        "pure_visual": _spread(2, [0, 1, 2, 3, 4], 140, classes(near_miss=15, no_grasp=4, success=4, n=40)),
        "goal2d": _spread(18, [0, 1, 2, 3, 4], 110, classes(near_miss=8, no_grasp=4, success=20, n=40)),
        "goal3d": _spread(30, [0, 1, 2, 3, 4], 80, classes(near_miss=1, no_grasp=4, success=31, n=40)),
        "state_control": _spread(36, [0, 1, 2, 3, 4], 70, classes(near_miss=0, no_grasp=0, success=40, n=40)),
    })
    assert [got[i]["Verdict"] for i in (1, 2, 3)] == ["reproduced"] * 3  # No Grasp 4 of 40 in every policy: TOST
    assert "5 policies" in got[1]["This build"] and "Welch t over policies" in got[1]["Test"]
    assert "TOST over policies, margin 0.1" in got[3]["Test"]
    assert got[1]["Resolvable at 80 % power"].endswith("points")
    assert (tmp_path / "f.md").read_text().count("5 policies per row") == 1  # exact: a count of a string


def test_a_gap_one_policys_episodes_resolve_is_not_resolved_across_policies(default_config, tmp_path):
    # 2D's policies spread from 8 to 32 of 40; pooled over 200 episodes 3D's 116 against 2D's 100 is p ~ 0.06 by
    # Fisher, and across five policies it is nowhere near resolved
    got = findings_of(default_config, tmp_path, {
        "pure_visual": _spread(0, [2, 3, 4, 3, 2], 140, classes(near_miss=15, no_grasp=4, success=4, n=40)),
        "goal2d": _spread(8, [0, 24, 4, 20, 12], 110, classes(near_miss=8, no_grasp=4, success=20, n=40)),
        "goal3d": _spread(20, [0, 6, 2, 4, 4], 80, classes(near_miss=1, no_grasp=20, success=31, n=40)),
        "state_control": _spread(36, [0, 1, 2, 3, 4], 70, classes(near_miss=0, no_grasp=0, success=40, n=40)),
    })
    assert got[1]["Verdict"] == "same direction, not resolved"
    assert got[3]["Verdict"] == "not reproduced"  # No Grasp 4 against 20 of 40 in every policy: resolved apart
    gaps = [float(g.split()[0]) for g in got[1]["Resolvable at 80 % power"].split("; ")]
    assert gaps[1] > 16  # 2D against 3D: a 16-point gap (100 vs 116 of 200) could hide in this spread


def test_a_dry_run_plans_k_policies_per_row(tmp_path):
    out = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "-d", str(tmp_path), "-n",
                          "--cores", "2", "results/tables/table5_1.csv", "--config", "replicates=3"],
                         capture_output=True, text=True, check=True).stdout
    counts = {line.split()[0]: int(line.split()[1]) for line in out.splitlines()
              if len(line.split()) == 2 and line.split()[1].isdigit()}
    assert counts["train"] == 4 * 3 and counts["stability"] == 4 * 3  # 4 rows x 3 policies, one run each
    assert "results/runs/goal3d@2/stability/run_0.episodes.parquet" in out


def test_two_builds_side_by_side_flag_a_claim_resolved_both_ways_and_a_mean_outside_the_other_interval(
        default_config, tmp_path):
    from ocpipe.study import builds

    runs = tmp_path / "runs"
    second = builds.second_build(default_config)
    assert targets.policies(second, "goal2d")[0] == "goal2d@5"
    low, high = classes(near_miss=15, no_grasp=4, success=4, n=40), classes(near_miss=1, no_grasp=4, success=31, n=40)
    same = {"pure_visual": _spread(2, [0, 1, 2, 3, 4], 140, low), "goal2d": _spread(18, [0, 1, 2, 3, 4], 110, low),
            "goal3d": _spread(30, [0, 1, 2, 3, 4], 80, high),
            "state_control": _spread(36, [0, 1, 2, 3, 4], 70, high)}
    write_rows(default_config, runs, same)
    write_rows(second, runs, same)
    assert builds.write(default_config, "findings_main", tmp_path / "a.csv", tmp_path / "a.rows.csv",
                        tmp_path / "a.md", str(runs)) == (True, True)
    # the second build's 3D below its 2D, resolved: finding 1's second claim goes the other way
    write_rows(second, runs, {**same, "goal3d": _spread(6, [0, 1, 2, 3, 4], 80, high)})
    assert builds.write(default_config, "findings_main", tmp_path / "b.csv", tmp_path / "b.rows.csv",
                        tmp_path / "b.md", str(runs)) == (False, False)
    f = builds.compare_findings(default_config, "findings_main", str(runs))
    assert f["Resolved both ways"].to_list() == ["yes", "no", "no"]
    assert "policies 0-4" in f.columns[2] and "policies 5-9" in f.columns[4]
    text = (tmp_path / "b.md").read_text()
    assert text.count("FAIL") == 2


def test_a_row_without_weights_keeps_the_columns_of_its_replicated_neighbours(default_config, tmp_path):
    import polars as pl

    from ocpipe.study import registry, tables

    runs, uncapped = tmp_path / "runs", {**default_config, "table_replicates": {}}  # Table 5.4 at K = 5
    write_rows(uncapped, runs, {"encoder_slots_ssl": _spread(10, [0, 2, 4, 6, 8], 110, classes(1, 1, 20, n=40))})
    rows = report.table_rows(uncapped, "table5_4", (inputs.STABILITY,), str(runs))
    for row in rows:
        if row.status is None:
            row.data[inputs.TRAIN_LOG] = pl.DataFrame({"epoch": [1], "seconds": [60.0]})
    t = tables.build(registry.TABLES["table5_4"].columns, rows)
    assert "SR std over policies" in t.columns and "SR std" not in t.columns
    by = {r["Method"]: r for r in t.iter_rows(named=True)}
    assert by["DINO CLS"]["SR std over policies"] is None and by["DINO CLS"]["Status"].startswith("needs weights")
    assert by["slots_ssl 14 slots (offline)"]["Policies"] == 5


def test_each_policy_keeps_its_own_best_epoch_and_peak_reward(default_config, tmp_path):
    import json

    runs, default_config = tmp_path / "runs", {**default_config, "table_replicates": {}}  # Table 5.7 at K = 5
    write_rows(default_config, runs, {e: _spread(4, [0, 1, 2, 3, 4], 120, classes(1, 1, 5, n=40))
                                      for e in ("pure_visual", "window20", "window40")})
    # policy 3 of T=5 picks its first checkpoint, whose sweep returned 2.0 per episode; the others their last (1.0)
    pid = targets.policies(default_config, "pure_visual")[3]
    sweep = inputs.SWEEP.files(default_config, pid, str(runs))[0]
    import polars as pl
    episodes = pl.read_parquet(sweep)
    epoch = episodes["checkpoint"].min()
    first = pl.col("checkpoint") == epoch
    episodes.with_columns(**{"return": pl.when(first).then(2.0).otherwise(pl.col("return"))}).write_parquet(sweep)
    best = inputs.BEST.files(default_config, pid, str(runs))[0]
    Path(best).write_text(json.dumps({"epoch": epoch, "sweep": [{"checkpoint": epoch, "mean_return": 2.0}]}))
    from ocpipe.study import findings

    rows = findings.by_experiment(report.table_rows(default_config, "table5_7", (inputs.BEST, inputs.SWEEP), str(runs)))
    label, peaks = findings._peak_returns(rows, "pure_visual")
    assert label == "T=5"
    assert [set(p) for p in peaks] == [{1.0}, {1.0}, {1.0}, {2.0}, {1.0}]  # exact: literal returns, in policy order
    assert [b["epoch"] for b in rows["pure_visual"].data[inputs.BEST]][3] == epoch
