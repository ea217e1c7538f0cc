"""The findings table on synthetic episode files whose verdicts are known, and the checks it is built from."""

from synthetic_runs import classes, write_rows

from ocpipe.stats import by_policy, pooled
from ocpipe.study import findings, report, targets


def test_an_order_is_reproduced_only_when_the_episodes_resolve_it():
    assert pooled.rate_less("a", (10, 120), "b", (60, 120)).outcome == "holds"
    assert pooled.rate_less("a", (55, 120), "b", (60, 120)).outcome == "unresolved"
    assert pooled.rate_less("a", (60, 120), "b", (55, 120)).outcome == "opposite"
    assert pooled.rate_less("a", (0, 4), "b", (0, 4)).outcome == "tie"  # equal figures lean neither way
    assert pooled.rate_less("a", (60, 120), "b", (10, 120)).outcome == "violated"
    check = pooled.rate_less("a", (10, 120), "b", (60, 120))
    assert check.p < 1e-9 and check.text == "SR a 10/120 (8.3 %) < b 60/120 (50.0 %)"


def test_equal_and_at_most_claims_on_one_policy_are_at_best_not_contradicted():
    # one policy's episodes offer no equivalence test: such a claim never 'holds', it fails when resolved against
    assert pooled.rate_equal("a", (50, 120), "b", (58, 120)).outcome == "not contradicted"
    assert pooled.rate_equal("a", (20, 120), "b", (60, 120)).outcome == "violated"
    assert pooled.rate_less("a", (58, 120), "b", (50, 120), strict=False).outcome == "not contradicted"
    assert pooled.rate_less("a", (90, 120), "b", (50, 120), strict=False).outcome == "violated"
    assert pooled.rate_at_most("a", (1, 120), 0.05).outcome == "not contradicted"
    assert pooled.rate_at_most("a", (30, 120), 0.05).outcome == "violated"
    assert pooled.rate_above("a", (70, 80), 0.5, "share").outcome == "holds"
    assert pooled.rate_above("a", (10, 80), 0.5, "share").outcome == "violated"


def test_verdicts_combine_checks_worst_first():
    verdict = by_policy.verdict
    assert verdict(["holds", "holds"]) == "reproduced"
    assert verdict(["holds", "unresolved"]) == "same direction, not resolved"
    assert verdict(["unresolved", "opposite"]) == "opposite direction, not resolved"
    assert verdict(["unresolved", "tie"]) == "no difference seen, not resolved"
    assert verdict(["holds", "violated"]) == "not reproduced"
    assert verdict(["holds", "not contradicted"]) == "not contradicted, could not resolve ±10 points"
    assert verdict(["not contradicted", "unresolved"]) == "same direction, not resolved"


def findings_of(config, tmp_path, rows, scope="findings_main"):
    runs = tmp_path / "runs"
    write_rows(config, runs, rows)
    frame = report.write_findings(config, scope, tmp_path / "f.csv", tmp_path / "f.md", str(runs))
    return {r["Finding"]: r for r in frame.iter_rows(named=True)}


def test_the_study_reproduced(one_policy_config, tmp_path):
    got = findings_of(one_policy_config, tmp_path, {
        "pure_visual": ([4, 3, 5], 140, classes(near_miss=40, no_grasp=12, success=12)),
        "goal2d": ([20, 18, 22], 110, classes(near_miss=20, no_grasp=12, success=60)),
        "goal3d": ([32, 30, 31], 80, classes(near_miss=2, no_grasp=14, success=93)),
        "state_control": ([39, 40, 38], 70, classes(near_miss=1, no_grasp=0, success=117)),
    })
    # finding 3's 'No Grasp about the same' needs an equivalence test, which one policy's episodes do not offer
    assert [got[i]["Verdict"] for i in (1, 2, 3)] == ["reproduced", "reproduced",
                                                      "not contradicted, one policy per row: no equivalence test"]
    assert got[1]["This build"] == ("SR Pure Visual 12/120 (10.0 %) < 2D-Spatial-Proj 60/120 (50.0 %); "
                                    "SR 2D-Spatial-Proj 60/120 (50.0 %) < Explicit-3D-GT 93/120 (77.5 %)")
    assert got[1]["p"] < 0.05 and got[1]["Study"] == "31.0 / 55.0 / 71.7 %"
    text = (tmp_path / "f.md").read_text()
    assert "| 1 | 5.1 | SR: Pure Visual < 2D < 3D |" in text and "Profile cpu-default." in text


def test_what_this_build_shows_when_it_differs_from_the_study(one_policy_config, tmp_path):
    got = findings_of(one_policy_config, tmp_path, {
        "pure_visual": ([4, 3, 5], 140, classes(near_miss=40, no_grasp=40, success=12)),
        "goal2d": ([20, 18, 22], 110, classes(near_miss=20, no_grasp=12, success=60)),
        "goal3d": ([18, 19, 17], 112, classes(near_miss=2, no_grasp=5, success=54)),  # 2D and 3D alike
        "state_control": ([39, 40, 38], 70, classes(near_miss=1, no_grasp=0, success=117)),
    })
    assert got[1]["Verdict"] == "opposite direction, not resolved"  # 60 against 54 of 120
    assert got[2]["Verdict"] == "not reproduced"  # 3D 2 steps longer than 2D in each of 120 episodes: resolved
    assert got[3]["Verdict"] == "not reproduced"  # No Grasp 40 against 5 of 120: not 'about the same'


def test_findings_without_weights_or_rows_say_what_is_missing(one_policy_config, tmp_path):
    rows = {exp: ([10, 10, 10], 100, classes(near_miss=10, no_grasp=10, success=30))
            for exp in targets.experiments_of(one_policy_config)}
    got = findings_of(one_policy_config, tmp_path, rows, scope="findings")
    assert len(got) == 12
    assert got[5]["Verdict"].startswith("not run: DINO CLS needs weights")
    # every weighting equal to uniform: one policy's episodes cannot show 'at most', only fail to reject it
    assert got[10]["Verdict"] == "not contradicted, one policy per row: no equivalence test"
    del one_policy_config["tables"]["table5_6"]["Cross-attention"]
    row = report.write_findings(one_policy_config, "findings", tmp_path / "g.csv", tmp_path / "g.md",
                                str(tmp_path / "runs")).row(6, named=True)
    assert row["Verdict"] == "not run: table5_6 has no row of experiment 'fusion_cross_attention'"
    assert findings.config_problems(one_policy_config) == [
        "tables.table5_6: no row runs experiment 'fusion_cross_attention', which finding 7 (cross-attention fits "
        "the training seeds better than concatenation, both equal held out (so its gap is larger)) compares"]


def test_a_renamed_row_label_keeps_its_finding(one_policy_config, tmp_path):
    rows = {exp: ([10, 10, 10], 100, classes(near_miss=10, no_grasp=10, success=30))
            for exp in targets.experiments_of(one_policy_config, ["table5_1", "table5_2"])}
    before = findings_of(one_policy_config, tmp_path / "a", rows).values()
    for table in ("table5_1", "table5_2"):
        one_policy_config["tables"][table] = {f"{label} (renamed)": exp
                                              for label, exp in one_policy_config["tables"][table].items()}
    after = list(findings_of(one_policy_config, tmp_path / "b", rows).values())
    assert [r["Verdict"] for r in after] == [r["Verdict"] for r in before]
    assert not any(r["Verdict"].startswith("not run") for r in after)
    assert "Pure Visual (renamed)" in after[0]["This build"]  # the checks name rows by their labels


def test_each_target_judges_the_findings_its_tables_cover(one_policy_config, tmp_path):
    got = findings_of(one_policy_config, tmp_path, {
        "stack_native": ([1, 2, 0], 196, classes(near_miss=10, no_grasp=90, success=3)),
        "stack_aligned": ([9, 8, 10], 180, classes(near_miss=12, no_grasp=70, success=27)),
    }, scope="findings_stackcube")
    assert sorted(got) == [11, 12]
    assert got[11]["Verdict"] == "reproduced"  # 27 against 3 of 120
    assert got[12]["Verdict"] == "reproduced" and "70/" in got[12]["This build"]  # No Grasp 70 of 93 failures
    rows = {exp: ([10, 10, 10], 100, classes(near_miss=10, no_grasp=10, success=30))
            for exp in targets.experiments_of(one_policy_config)}
    got = findings_of(one_policy_config, tmp_path / "all", rows, scope="findings_ablations")
    assert sorted(got) == list(range(4, 11))


def test_a_table_the_findings_cannot_read_is_refused_naming_the_finding(one_policy_config):
    cfg = {**one_policy_config, "tables": {**one_policy_config["tables"]}}
    cfg["tables"]["table5_5"] = {k: v for k, v in cfg["tables"]["table5_5"].items() if v != "head_slot_transformer"}
    cfg["tables"]["table5_9"] = {**cfg["tables"]["table5_9"], "Uniform again": "goal2d"}
    problems = findings.config_problems(cfg)
    assert any(p.startswith("tables.table5_5: no row runs experiment 'head_slot_transformer', which finding 6")
               for p in problems), problems
    assert any(p.startswith("tables.table5_9: experiment 'goal2d' runs in two rows; finding 10") for p in problems)
    del cfg["tables"]["table5_1"]  # the main target's figures read its rows, whatever else a profile runs
    assert "tables.table5_1: missing; every profile needs it" in " ".join(findings.config_problems(cfg))


def test_table_inputs_are_one_object_each_wherever_they_travel():
    import pickle

    from ocpipe.study import inputs

    for need in inputs.INPUTS.values():
        assert pickle.loads(pickle.dumps(need)) is need  # Snakemake pickles what reaches a script
    assert {inputs.STABILITY: 1}[inputs.INPUTS["stability"]] == 1
