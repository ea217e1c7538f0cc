"""Like for like: every table's rows differ only in what the study varied there, in both profiles; shared rows are
one experiment; each table's Markdown names the profile and its departures from the study's recipe."""

import polars as pl
import pytest
from conftest import REPO

from ocpipe.config import validate as cfgmod
from ocpipe.config.experiments import resolve
from ocpipe.study import conditions, registry, report

PROFILES = {"default": [REPO / "config" / "config.yaml"],
            "full": [REPO / "config" / "config.yaml", REPO / "config" / "thesis.yaml"]}


@pytest.fixture(params=list(PROFILES))
def profile(request):
    return cfgmod.load(*PROFILES[request.param])


def test_rows_of_every_table_differ_only_in_what_the_study_varied(profile):
    problems = [p for table in registry.TABLES for p in conditions.unlike_rows(profile, table)]
    assert problems == []


def test_a_row_that_differs_in_something_else_is_named(default_config):
    default_config["experiments"]["weight_time"]["goal_norm"] = "none"
    problems = conditions.unlike_rows(default_config, "table5_9")
    assert problems and all("goal_norm 'zscore' vs 'none'" in p or "goal_norm 'none' vs 'zscore'" in p
                            for p in problems)
    assert len(problems) == 3  # weight_time against each of the other three rows


def test_the_control_may_differ_only_in_what_reading_the_true_pose_needs(default_config):
    assert conditions.unlike_rows(default_config, "table5_1") == []
    default_config["experiments"]["state_control"]["window"] = 3
    assert any("window" in p and "Privileged state" in p for p in conditions.unlike_rows(default_config, "table5_1"))


def test_rows_the_study_shared_between_tables_are_one_experiment(profile):
    tables = profile["tables"]
    approx = {tables["table5_1"]["2D-Spatial-Proj"], tables["table5_3"]["approx-128"], tables["table5_9"]["Uniform"]}
    pure = {tables["table5_1"]["Pure Visual"], tables["table5_8"]["7-DoF"]}
    assert len(approx) == 1 and len(pure) == 1
    goal2d, pure_visual = resolve(profile, approx.pop()), resolve(profile, pure.pop())
    assert goal2d["goal"] == "2d" and goal2d["goal_calibration"] == "approx" and goal2d["resolution"] == 128
    assert pure_visual["goal"] == "none"
    # the tables the study ran without a goal
    for table in ("table5_5", "table5_6", "table5_7", "table5_8"):
        assert {resolve(profile, e)["goal"] for e in tables[table].values()} == {"none"}, table
    for table in ("table5_4", "table5_9"):
        assert {resolve(profile, e)["goal_calibration"] for e in tables[table].values()} == {"approx"}, table


def test_tables_whose_variable_the_read_out_goes_around_run_every_row_without_it(profile):
    for table in ("table5_4", "table5_5", "table5_6"):
        for label, exp in profile["tables"][table].items():
            s = resolve(profile, exp)
            assert (s["object_readout"], s["readout_scenes"], s["visual_dropout"]) == (False, False, 0.0), label
    # their slot and concatenation rows are the main table's recipe less the read-out, nothing else
    readout = {"name", "object_readout", "readout_scenes", "visual_dropout"}
    for table, main_exp in (("table5_4", "goal2d"), ("table5_6", "pure_visual")):
        main = resolve(profile, main_exp)
        ours = resolve(profile, profile["tables"][table][next(iter(profile["tables"][table]))
                                                         if table == "table5_6" else "slots_ssl 14 slots (offline)"])
        assert {k for k in main if main[k] != ours[k]} <= readout, table


def test_no_table_row_may_take_the_goal_minus_the_hand(default_config):
    assert [p for table in registry.TABLES for p in conditions.barred(default_config, table)] == []
    default_config["policy"]["goal_relative"] = "tcp"
    problems = conditions.barred(default_config, "table5_1")
    assert len(problems) == 4 and all("goal_relative 'tcp', which must be 'none'" in p for p in problems)
    assert "tables.table5_1: row '2D-Spatial-Proj' (experiment 'goal2d')" in problems[1]


def test_a_read_out_on_a_row_it_would_go_around_is_refused_by_config_check(default_config):
    from ocpipe.config.errors import ConfigError
    from ocpipe.study import findings

    default_config["experiments"]["fusion_cross_attention"]["object_readout"] = True
    with pytest.raises(ConfigError, match=r"tables.table5_6: row 'Cross-attention' \(experiment "
                                          r"'fusion_cross_attention'\) has object_readout True, which must be False"):
        findings.check_config(default_config)


def test_window_rows_get_one_training_budget_in_the_study_proportions(profile):
    epochs = {label: resolve(profile, e)["epochs"] for label, e in profile["tables"]["table5_7"].items()}
    base = profile["policy"]["epochs"]
    assert epochs["T=5"] == base
    assert epochs["T=20"] == round(base * 0.44) and epochs["T=40"] == round(base * 0.22)  # 680 : 300 : 150


def test_the_full_profile_runs_the_study_recipe_and_the_default_names_its_departures(default_config):
    full = cfgmod.load(*PROFILES["full"])
    assert conditions.departures(full, "table5_3") == []
    dep = conditions.departures(default_config, "table5_1")
    assert "object_readout True (not Privileged state (control))" in dep
    assert "evaluation.execute_actions 1" in dep and "width 64" in dep and "demos.num_demos 100" in dep
    line = conditions.footer(default_config, "table5_1")
    assert line.startswith("Profile cpu-default. Rows differ only in: goal (and state_control")
    assert conditions.footer(full, "table5_3").endswith("No departure from the study's recipe.")


def test_a_departure_that_is_not_the_same_for_every_row_names_its_rows(default_config):
    dep = conditions.departures(default_config, "table5_1")
    assert "visual_dropout 0.5 (not Privileged state (control))" in dep  # the control has no visual token to blank
    # Table 5.4's rows all run without the read-out and dropout, as the study did; dense DINO alone differs, in T, H
    # and batch (the shorter list of rows is named)
    dep = [d for d in conditions.departures(default_config, "table5_4") if "(" in d]
    assert dep == ["window 1 (DINO 14x14 dense only)", "horizon 1 (DINO 14x14 dense only)",
                   "batch_size 4 (DINO 14x14 dense only)"]


def test_table_markdown_ends_with_the_conditions_line(default_config, tmp_path):
    frame = pl.DataFrame({"Method": ["a"], "SR mean": [0.5]})
    report.write(frame, tmp_path / "t.csv", tmp_path / "t.md", "T", conditions.footer(default_config, "table5_9"))
    last = (tmp_path / "t.md").read_text().rstrip().splitlines()[-1]
    assert last.startswith("Profile cpu-default. Rows differ only in: loss_weighting;")
    assert pl.read_csv(tmp_path / "t.csv").columns == ["Method", "SR mean"]  # the CSV stays a plain table


def test_the_study_recipe_is_read_from_the_full_profile_alone(default_config, tmp_path, monkeypatch):
    """config/thesis.yaml is the one source of the study's recipe: a setting changed there moves the footers."""
    text = conditions.STUDY_PROFILE.read_text()
    assert "  width: 256" in text
    changed = tmp_path / "thesis.yaml"
    changed.write_text(text.replace("  width: 256", "  width: 64"))  # the default profile's width
    assert "width 64" in conditions.departures(default_config, "table5_1")
    monkeypatch.setattr(conditions, "STUDY_PROFILE", changed)
    conditions.study_recipe.cache_clear()
    try:
        assert not any(d.startswith("width ") for d in conditions.departures(default_config, "table5_1"))
    finally:
        monkeypatch.undo()
        conditions.study_recipe.cache_clear()
