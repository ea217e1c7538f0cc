"""Tables 5.3-5.11 and figures 5.5-5.7: which files each row reads, rows that need weights, and the columns."""

import json

import polars as pl
import pytest
import torch
from synthetic_runs import classes, write_rows

from ocpipe import paths
from ocpipe.config.validate import deep_merge
from ocpipe.evaluation import jobs
from ocpipe.study import inputs, registry, report, tables, targets


def episodes(run, successes, steps_=None):
    n = len(successes)
    return pl.DataFrame({"exp": ["e"] * n, "checkpoint": [16] * n, "run": [run] * n, "seed": list(range(n)),
                         "success": successes, "steps": steps_ or [60] * n, "trivial": [False] * n,
                         "return": [1.0] * n})


def test_rows_needing_weights_are_reported_not_built(default_config):
    skip = targets.unavailable(default_config, "table5_4")
    assert set(skip) == {"DINO CLS", "DINO 4x4", "DINO 14x14 dense", "SPOT 14 slots"}
    assert "encoders.dino.checkpoint" in skip["DINO CLS"] and "encoders.spot" in skip["SPOT 14 slots"]
    files = targets.inputs(default_config, "table5_4")
    # only the offline slots_ssl row is built, as the table's 3 policies (config table_replicates)
    assert {f.split("/")[2] for f in files} == {"encoder_slots_ssl", "encoder_slots_ssl@1", "encoder_slots_ssl@2"}
    assert "dino_cls" not in targets.experiments_of(default_config)


def test_a_tables_image_stores_leave_out_the_control_and_rows_without_weights(default_config):
    assert targets.image_stores(default_config, "table5_1") == ["PickCube-v1_dual_128_slots_ssl"]  # 3 rows, 1 store
    assert targets.image_stores(default_config, "table5_10") == ["StackCube-v1_native_128_slots_ssl",
                                                                 "StackCube-v1_dual_128_slots_ssl"]
    assert targets.image_stores(default_config, "table5_4") == ["PickCube-v1_dual_128_slots_ssl"]  # no DINO weights


def test_given_weights_put_those_rows_in_the_graph(default_config, tmp_path):
    config = deep_merge(default_config, {"encoders": {"dino": {"checkpoint": str(tmp_path / "dino.pth")}}})
    assert set(targets.unavailable(config, "table5_4")) == {"SPOT 14 slots"}
    assert any("/dino_dense/" in f for f in targets.inputs(config, "table5_4"))


def test_every_table_names_only_defined_experiments_and_declared_inputs(default_config):
    assert set(default_config["tables"]) == set(registry.TABLES)
    declared = set(inputs.INPUTS.values())
    for table, spec in registry.TABLES.items():
        assert set(spec.needs) <= declared, table
        for exp in targets.rows(default_config, table).values():
            for need in spec.needs:
                assert need.files(default_config, exp), (table, exp, need)


def test_representation_table_keeps_rows_without_weights_with_their_settings(default_config):
    rows = report.table_rows(default_config, "table5_4", needs=())
    ok = [r for r in rows if r.status is None]
    ok[0].data = {inputs.STABILITY: pl.concat([episodes(0, [True, False]), episodes(1, [True, True])]),
                  inputs.TRAIN_LOG: pl.DataFrame({"epoch": [1, 2], "seconds": [30.0, 90.0]})}
    t = tables.build(registry.TABLES["table5_4"].columns, rows)
    by = {r["Method"]: r for r in t.iter_rows(named=True)}
    dense, ssl = by["DINO 14x14 dense"], by["slots_ssl 14 slots (offline)"]
    assert dense["Status"].startswith("needs weights") and dense["SR mean"] is None
    assert (dense["Visual tokens"], dense["T"], dense["H"], dense["Batch"]) == (392, 1, 1, 4)
    assert by["DINO CLS"]["Visual tokens"] == 2 and by["DINO 4x4"]["Visual tokens"] == 32
    assert ssl["Status"] == "ok" and ssl["Visual tokens"] == 14
    assert ssl["SR mean"] == 0.75 and ssl["Minutes/epoch"] == 1.0  # exact: (1/2 + 1) / 2 and (30 + 90) / 2 / 60


def test_generalization_gap_is_training_seed_sr_minus_held_out_sr():
    row = tables.Row("Concatenation", {"fusion": "concat"},
                     {inputs.STABILITY: pl.concat([episodes(0, [True, False, False, False]), episodes(1, [False] * 4)]),
                      inputs.TRAIN_SEEDS: episodes(0, [True, True, False, False])})
    r = tables.build(registry.TABLES["table5_6"].columns, [row]).row(0, named=True)
    # exact: 2/4, (1/4 + 0) / 2 and their difference are exact in binary
    assert r["Training-seed SR"] == 0.5 and r["Held-out SR"] == 0.125
    assert r["Gap"] == 0.375  # exact: as above


def _fake_run(runs, exp, n_runs=3, epochs=(8, 16), pos_rows=85):
    (runs / exp / "stability").mkdir(parents=True)
    for r in range(n_runs):
        episodes(r, [True, False, r == 0]).write_parquet(runs / exp / "stability" / f"run_{r}.episodes.parquet")
    episodes(0, [True] * 3 + [False] * 27).write_parquet(runs / exp / "training_time.episodes.parquet")
    (runs / exp / "checkpoints").mkdir()
    for e in epochs:
        torch.save({"model": {"pos": torch.zeros(pos_rows, 4), "w": torch.zeros(3, 5)}, "parameters": 1234},
                   runs / exp / "checkpoints" / f"epoch_{e:04d}.pt")
    pl.DataFrame({"epoch": [1, 2], "seconds": [60.0, 60.0]}).write_parquet(runs / exp / "train_log.parquet")
    sweep = [{"checkpoint": 8, "sr": 0.0, "mean_return": 1.5}, {"checkpoint": 16, "sr": 0.5, "mean_return": 4.0}]
    (runs / exp / "best.json").write_text(json.dumps({"epoch": 16, "sweep": sweep}))


def test_window_and_head_tables_read_checkpoints_and_sweeps(one_policy_config, tmp_path):
    runs = tmp_path / "runs"
    for exp, pos in (("pure_visual", 85), ("window20", 340), ("window40", 680)):
        _fake_run(runs, exp, pos_rows=pos)
    t = report.write_table(one_policy_config, "table5_7", tmp_path / "t7.csv", tmp_path / "t7.md", runs_dir=runs)
    assert t["Sequence length"].to_list() == [85, 340, 680] and t["T"].to_list() == [5, 20, 40]
    assert t["Reward at peak"].to_list() == [4.0] * 3 and t["Best epoch"].to_list() == [16] * 3
    epochs = one_policy_config["policy"]["epochs"]  # one budget: the study's 680 / 300 / 150 epochs in proportion
    assert t["Minutes/epoch"].to_list() == [1.0] * 3
    assert t["Epochs"].to_list() == [epochs, round(epochs * 0.44), round(epochs * 0.22)]
    for exp in ("head_flatten", "head_deepsets", "head_weighted_pool", "head_slot_transformer"):
        _fake_run(runs, exp)
    t = report.write_table(one_policy_config, "table5_5", tmp_path / "t5.csv", tmp_path / "t5.md", runs_dir=runs)
    assert t["Parameters"].to_list() == [1234] * 4  # what training recorded, not a count of the state dict
    # one 30-episode training-time run per head, not the stability runs: 3 of 30 with its Wilson interval
    # exact: 3 / 30 rounds once to the double nearest 0.1; approx only because 0.1 is written in decimal
    assert t["SR"].to_list() == [pytest.approx(0.1)] * 4 and t["Runs"].to_list() == [1] * 4
    assert t["Episodes per run"].to_list() == [30] * 4
    # derived: the expected sides are the Wilson bounds of 3 in 30 (0.0345999, 0.2562108) rounded to 4 decimals, so
    # off by <= 5e-5; scipy's float64 adds ~1e-16
    assert t["SR 95 % low"][0] == pytest.approx(0.0346, abs=5e-5)
    assert t["SR 95 % high"][0] == pytest.approx(0.2562, abs=5e-5)  # derived: as above
    assert pl.read_csv(tmp_path / "t5.csv")["Head"].to_list() == ["flatten", "deepsets", "weighted_pool",
                                                                  "slot_transformer"]


def test_figures_draw_rows_and_mark_missing_weights(one_policy_config, tmp_path):
    runs = tmp_path / "runs"
    _fake_run(runs, "encoder_slots_ssl")
    report.write_figure(one_policy_config, "fig5_5", tmp_path / "fig5_5.png", runs_dir=runs)
    assert (tmp_path / "fig5_5.png").stat().st_size > 5_000
    stack = pl.DataFrame({"class": ["No Grasp", "Grasp No Stack", "Success"], "trivial": [False] * 3,
                          "grasp": [False, True, True], "lift": [False, True, True],
                          "near target": [False, False, True], "success": [False, False, True]})
    for exp in ("stack_native", "stack_aligned"):
        (runs / exp).mkdir()
        stack.write_parquet(runs / exp / "failures.parquet")
    report.write_figure(one_policy_config, "fig5_7", tmp_path / "fig5_7.png", runs_dir=runs)
    t = report.write_table(one_policy_config, "table5_11", tmp_path / "t11.csv", tmp_path / "t11.md", runs_dir=runs)
    assert t["Method"].to_list() == ["Aligned (base + side, 2D goal)"]  # the study's Table 5.11: aligned only
    assert t["Grasp No Stack"].to_list() == [1] and t["Total"].to_list() == [3]


def test_training_seed_runs_draw_from_the_demo_seeds(default_config):
    demo_seeds = list(range(0, 300, 3))
    a = jobs.seeds_for("train_seeds", default_config["evaluation"], 0, episode_seeds=demo_seeds)
    assert a == jobs.seeds_for("train_seeds", default_config["evaluation"], 0, episode_seeds=demo_seeds)
    assert len(a) == default_config["evaluation"]["stability_episodes"] and set(a) <= set(demo_seeds)
    assert len(jobs.seeds_for("train_seeds", default_config["evaluation"], 0, episode_seeds=[4, 7])) == 2


def test_stackcube_failure_table_always_has_grasp_no_stack(tmp_path):
    stack = pl.DataFrame({"class": ["No Grasp", "Success"], "trivial": [False, False]})
    t = tables.table5_2({"Native": stack}, always=("Grasp No Stack",)).row(0, named=True)
    assert t["Grasp No Stack"] == 0 and t["Grasp No Stack %"] == 0.0 and t["Total"] == 2
    assert "Grasp No Stack" not in tables.table5_2({"Native": stack}).columns


def test_run_files_come_from_the_path_patterns_under_any_runs_folder(default_config):
    assert inputs.BEST.files(default_config, "goal2d") == ["results/runs/goal2d/best.json"]
    assert inputs.STABILITY.files(default_config, "goal2d", runs_dir="/x/runs")[0] == (
        "/x/runs/goal2d/stability/run_0.episodes.parquet")
    assert inputs.SWEEP.files(default_config, "goal2d") == ["results/runs/goal2d/sweep.episodes.parquet"]
    # each episodes file has its steps beside it; anything else is named, not guessed at
    assert paths.steps_beside("/x/runs/goal2d/stability/run_0.episodes.parquet") == (
        "/x/runs/goal2d/stability/run_0.steps.parquet")
    with pytest.raises(ValueError, match=r"run_0.parquet: not an evaluation run's episodes file"):
        paths.steps_beside("/x/run_0.parquet")


def test_store_names_fill_the_path_patterns():
    assert paths.frames_store("PickCube-v1_dual_128") == "results/frames/PickCube-v1_dual_128.zarr"
    assert paths.named(paths.ATTENTION_FIGURE, "PickCube-v1_dual_128_spot") == (
        "results/figures/attention_PickCube-v1_dual_128_spot.png")
    assert paths.features_diagnostics("StackCube-v1_native_64_slots_ssl") == paths.FEATURES_DIAGNOSTICS.format(
        task="StackCube-v1", cams="native", res=64, encoder="slots_ssl")
    with pytest.raises(ValueError, match="no store name fields"):
        paths.named(paths.BEST, "PickCube-v1_dual_128")


def test_tables_put_each_rows_figures_in_its_row(one_policy_config, tmp_path):
    """Rows with different success rates, lengths and failure classes: a swapped row or a wrong formula shows."""
    runs = tmp_path / "runs"
    write_rows(one_policy_config, runs, {
        "pure_visual": ([4, 3, 5], 140, classes(near_miss=40, no_grasp=12, success=12)),
        "goal2d": ([20, 18, 22], 110, classes(near_miss=20, no_grasp=12, success=60)),
        "goal3d": ([32, 30, 31], 80, classes(near_miss=2, no_grasp=14, success=93)),
        "state_control": ([39, 40, 38], 70, classes(near_miss=1, no_grasp=0, success=117)),
    })
    t1 = report.write_table(one_policy_config, "table5_1", tmp_path / "t1.csv", tmp_path / "t1.md", str(runs))
    by = {r["Method"]: r for r in t1.iter_rows(named=True)}
    assert list(by) == ["Pure Visual", "2D-Spatial-Proj", "Explicit-3D-GT", "Privileged state (control)"]
    expected = {"Pure Visual": ([4, 3, 5], 140), "2D-Spatial-Proj": ([20, 18, 22], 110),
                "Explicit-3D-GT": ([32, 30, 31], 80), "Privileged state (control)": ([39, 40, 38], 70)}
    for label, (per_run, length) in expected.items():
        rates = [k / 40 for k in per_run]
        # derived: 3 float64 sums and a division, in numpy's order and in Python's (<= 1e-15 relative); approx's 1e-6
        # default is far above that and far below a swapped row (rates differ by >= 1/40)
        assert by[label]["SR mean"] == pytest.approx(sum(rates) / 3)
        # derived: numpy's and polars' sample std of 3 rates <= 1: a few float64 sums, off by ~1e-15, so <= 1e-13
        # relative at these stds (>= 0.025); approx's 1e-6 default is far above that and far below a swapped row
        assert by[label]["SR std"] == pytest.approx(float(pl.Series(rates).std()))
        # exact: synthetic_runs spreads the 40 lengths by (i % 7) - 3, a sum of -5; integer sums over 40 and 3 runs of
        # one dyadic mean are exact in binary
        assert by[label]["Episode length mean"] == length + sum(i % 7 - 3 for i in range(40)) / 40
        assert (by[label]["Runs"], by[label]["Episodes per run"]) == (3, 40)
    t2 = report.write_table(one_policy_config, "table5_2", tmp_path / "t2.csv", tmp_path / "t2.md", str(runs))
    by2 = {r["Method"]: r for r in t2.iter_rows(named=True)}
    assert [by2[m]["Near Miss"] for m in by] == [40, 20, 2, 1] and [by2[m]["Success"] for m in by] == [12, 60, 93, 117]
    assert by2["Pure Visual"]["Near Miss %"] == 100 * 40 / 120  # exact: 4000 / 120 rounded once on both sides
    assert by2["Explicit-3D-GT"]["Drop"] == 120 - 93 - 2 - 14
    assert (tmp_path / "t1.md").read_text().rstrip().splitlines()[-1].startswith("Profile cpu-default.")


def test_markdown_keeps_small_p_values_readable():
    table = pl.DataFrame({"Finding": [1, 2, 3], "p": [5.78e-05, 0.0, 0.1234], "Note": ["a", None, "c"]})
    md = report.markdown(table, "t")
    assert "| 1 | 5.8e-05 | a |" in md and "| 2 | 0.000 | — |" in md and "| 3 | 0.123 | c |" in md


def test_csv_keeps_p_values_whole_and_rounds_other_floats(tmp_path):
    table = pl.DataFrame({"SR": [0.123456], "p": [2.1e-06], "p vs baseline": [0.0123456789], "Note": [None]})
    tables.write_csv(table, tmp_path / "t.csv")
    back = pl.read_csv(tmp_path / "t.csv")
    # exact: the shortest decimal that parses back to the same float, and 4 decimals as written
    assert back.row(0) == (0.1235, 2.1e-06, 0.0123456789, None)


def test_summary_prints_table5_1_then_the_findings_and_two_builds_then_the_other_tables(tmp_path):
    from ocpipe.study.summary import _tables_in_order

    (tmp_path / "tables").mkdir()
    for name in ("table5_1", "table5_2", "table5_10", "findings_stackcube", "findings_main"):
        (tmp_path / "tables" / f"{name}.md").write_text(name)
    order = lambda: [p.stem for p in _tables_in_order(tmp_path)]  # noqa: E731
    assert order() == ["table5_1", "findings_main", "findings_stackcube", "table5_2", "table5_10"]
    (tmp_path / "tables" / "two_builds_findings_main.md").write_text("two builds")
    assert order() == ["table5_1", "findings_main", "findings_stackcube", "two_builds_findings_main", "table5_2",
                       "table5_10"]
    (tmp_path / "tables" / "findings.md").write_text("all twelve")
    assert order() == ["table5_1", "findings", "two_builds_findings_main", "table5_2", "table5_10"]


def test_a_checkpoint_without_its_parameter_count_fails_table5_5_only(one_policy_config, tmp_path):
    runs = tmp_path / "runs"
    for exp in ("head_flatten", "head_deepsets", "head_weighted_pool", "head_slot_transformer", "pure_visual",
                "window20", "window40"):
        _fake_run(runs, exp)
        for ckpt in (runs / exp / "checkpoints").glob("*.pt"):
            state = torch.load(ckpt, weights_only=False)
            del state["parameters"]
            torch.save(state, ckpt)
    t = report.write_table(one_policy_config, "table5_7", tmp_path / "t7.csv", tmp_path / "t7.md", runs_dir=runs)
    assert t["Sequence length"].to_list() == [85, 85, 85]  # Table 5.7 reads the sequence length alone
    with pytest.raises(ValueError, match="before training recorded its parameter count"):
        report.write_table(one_policy_config, "table5_5", tmp_path / "t5.csv", tmp_path / "t5.md", runs_dir=runs)
