"""The levers table: each lever beside its experiment's baseline, tested on the same validation episodes."""

import polars as pl
import pytest
from scipy.stats import fisher_exact

from ocpipe.config import validate as C
from ocpipe.config.experiments import resolve, resolve_lever
from ocpipe.study import levers


def _files(tmp_path, name, successes, n=20, seconds=(30.0, 30.0), err=0.01, readout=True):
    d = tmp_path / name
    d.mkdir()
    pl.DataFrame({"epoch": [1, 2], "seconds": list(seconds), "val_joint_err_rad": [0.02, err]}).write_parquet(
        d / "log.parquet")
    pl.DataFrame({"seed": list(range(n)), "success": [i < successes for i in range(n)],
                  "trivial": [False] * n}).write_parquet(d / "eps.parquet")
    est = [[0.01, 0.0, 0.02]] * 3 if readout else [[float("nan")] * 3] * 3
    pl.DataFrame({"obj_est": est, "obj_pos": [[0.0, 0.0, 0.02]] * 3,
                  "is_grasped": [False, False, True]}).write_parquet(d / "steps.parquet")
    return d / "log.parquet", d / "eps.parquet", d / "steps.parquet"


def test_each_lever_is_tested_against_its_experiments_baseline(tmp_path):
    config = {"profile": "test", "levers": {"episodes": 20, "adoption_max_drop_points": 3, "sets": {
        "a": {"experiment": "goal2d"}, "a_off": {"experiment": "goal2d", "policy": {"visual_dropout": 0.0}},
        "b": {"experiment": "goal3d", "policy": {"visual_head": "none"}}}}}
    inputs = {"a": [_files(tmp_path, "a", 4)], "a_off": [_files(tmp_path, "a_off", 14, err=0.02)],
              "b": [_files(tmp_path, "b", 9, readout=False)]}
    table = levers.write(config, inputs, tmp_path / "levers.csv", tmp_path / "levers.md")
    rows = {r["Lever"]: r for r in table.iter_rows(named=True)}
    assert rows["a"]["Changes"] == "baseline" and rows["a"]["p vs baseline"] is None
    assert rows["a_off"]["Changes"] == "visual_dropout=0.0"
    assert (rows["a_off"]["Successes"], rows["a_off"]["Episodes"], rows["a_off"]["SR"]) == (14, 20, 0.7)
    # exact: the product makes this same scipy call (two-sided) on the same integer table
    assert rows["a_off"]["p vs baseline"] == fisher_exact([[14, 6], [4, 16]])[1]
    assert rows["a_off"]["p vs baseline"] < 0.05  # 14/20 against 4/20 is resolved
    assert rows["b"]["p vs baseline"] is None  # goal3d has no baseline lever here
    assert rows["a"]["Train min"] == 1.0 and rows["a_off"]["Open-loop joint error (rad)"] == 0.02
    assert rows["a"]["Read-out error (cm)"] == 1.0 and rows["b"]["Read-out error (cm)"] is None
    md = (tmp_path / "levers.md").read_text()
    assert "same 20 seeds of the validation pool" in md and "Fisher's exact test" in md
    assert "| a_off | goal2d | visual_dropout=0.0 |" in md
    assert pl.read_csv(tmp_path / "levers.csv")["Lever"].to_list() == ["a", "a_off", "b"]


def test_a_lever_resolves_over_its_experiment_and_bad_levers_are_named(default_config):
    lever = resolve_lever(default_config, "goal2d_dropout")
    assert lever == {**resolve(default_config, "goal2d"), "dropout": 0.1, "epochs": 16, "save_every": 8,
                     "lr_schedule": "constant", "name": "goal2d_dropout"}
    # a lever's epochs is the base budget its experiment takes its share of, and its own share replaces the
    # experiment's: never both (window20 trains 0.44 of the budget)
    sets = default_config["levers"]["sets"]
    sets["w_budget"] = {"experiment": "window20", "policy": {"epochs": 100}}
    sets["w_share"] = {"experiment": "window20", "policy": {"epoch_share": 0.5}}
    base = default_config["policy"]["epochs"]
    assert resolve_lever(default_config, "w_budget")["epochs"] == 44
    assert resolve_lever(default_config, "w_share")["epochs"] == round(base * 0.5)
    assert "epoch_share" not in resolve_lever(default_config, "w_share")
    del sets["w_budget"], sets["w_share"]
    bad = {**default_config, "levers": {
        "episodes": 500, "replicates": 1, "adoption_max_drop_points": 3, "build": ["goal2d", "goal2d_typo"], "sets": {
        **sets, "x": {"experiment": "nope"}, "y": {"experiment": "goal2d", "policy": {"visual_head": "none",
                                                                                       "object_readout": False}}}}}
    with pytest.raises(C.ConfigError) as err:
        C.validate(bad)
    msg = str(err.value)
    assert "levers.episodes: 500 episodes per lever, but the validation pool holds 200 seeds" in msg
    assert "levers.sets.x.experiment: 'nope' is not defined under experiments" in msg
    assert "levers.sets.y.policy.visual_head" in msg
    assert "levers.build: 'goal2d_typo' is not a lever under levers.sets" in msg
    assert "'goal2d' is not" not in msg
    with pytest.raises(C.ConfigError, match="levers.sets.z.policy.widht"):
        C.validate({**default_config, "levers": {"episodes": 2, "replicates": 1, "adoption_max_drop_points": 3,
                                                 "sets": {"z": {"experiment": "goal2d", "policy": {"widht": 3}}}}})


def test_a_lever_of_several_policies_is_tested_across_them(tmp_path):
    config = {"profile": "test", "levers": {"episodes": 20, "adoption_max_drop_points": 3, "sets": {
        "a": {"experiment": "goal2d"}, "a_off": {"experiment": "goal2d", "policy": {"visual_dropout": 0.0}}}}}
    # the baseline's policies spread from 2 to 18 of 20; the lever's sit at 12-13: pooled, 62 of 100 against 50
    # of 100 would be p ~ 0.11 by Fisher, and across policies the spread leaves it far from resolved
    inputs = {"a": [_files(tmp_path, f"a{i}", k) for i, k in enumerate((2, 18, 6, 14, 10))],
              "a_off": [_files(tmp_path, f"o{i}", k, err=0.02) for i, k in enumerate((12, 13, 12, 13, 12))]}
    table = levers.write(config, inputs, tmp_path / "levers.csv", tmp_path / "levers.md")
    rows = {r["Lever"]: r for r in table.iter_rows(named=True)}
    assert (rows["a_off"]["Policies"], rows["a_off"]["Successes"], rows["a_off"]["Episodes"]) == (5, 62, 100)
    assert rows["a"]["SR"] == 0.5  # exact: five rates k/20 whose mean is 10/20, each a multiple of 1/20 summed
    assert rows["a_off"]["p vs baseline"] > 0.2
    assert "Welch's t over the policies' SRs" in (tmp_path / "levers.md").read_text()


def test_a_cheaper_lever_is_adoptable_only_without_a_resolved_loss_or_a_drop_beyond_the_limit(tmp_path):
    config = {"profile": "test", "levers": {"episodes": 20, "adoption_max_drop_points": 3, "sets": {
        "a": {"experiment": "goal2d"}, "a_same": {"experiment": "goal2d", "policy": {"epochs": 10}},
        "a_loss": {"experiment": "goal2d", "policy": {"epochs": 2}},
        "a_noisy": {"experiment": "goal2d", "policy": {"epochs": 5}}}}}
    inputs = {"a": [_files(tmp_path, f"a{i}", k) for i, k in enumerate((10, 11, 10, 9, 10))],
              # 9.6 of 20 against 10: 2 points down, unresolved
              "a_same": [_files(tmp_path, f"s{i}", k) for i, k in enumerate((9, 10, 10, 9, 10))],
              # 4.4 of 20: 28 points down, resolved
              "a_loss": [_files(tmp_path, f"l{i}", k) for i, k in enumerate((4, 5, 4, 5, 4))],
              # 9 of 20 on average with a wide spread: 5 points down, not resolved, but beyond the 3-point limit
              "a_noisy": [_files(tmp_path, f"n{i}", k) for i, k in enumerate((2, 16, 5, 13, 9))]}
    table = levers.write(config, inputs, tmp_path / "levers.csv", tmp_path / "levers.md")
    rows = {r["Lever"]: r for r in table.iter_rows(named=True)}
    assert rows["a"]["Adoptable"] is None and rows["a"]["SR change (points)"] is None
    assert rows["a_same"]["SR change (points)"] == -2.0 and rows["a_same"]["p of a loss"] > 0.05
    assert rows["a_same"]["Adoptable"] == "yes"
    assert rows["a_loss"]["p of a loss"] < 0.05 and rows["a_loss"]["Adoptable"].startswith("no: a resolved loss")
    assert rows["a_noisy"]["SR change (points)"] == -5.0 and rows["a_noisy"]["p of a loss"] > 0.05
    assert rows["a_noisy"]["Adoptable"] == "no: the mean drops by more than 3 points"
    # exact: the two-sided p is twice the one-sided p of a loss where the lever is below, and doubling a float is exact
    assert 2 * rows["a_loss"]["p of a loss"] == rows["a_loss"]["p vs baseline"]
    assert "at most 3 points below the baseline's" in (tmp_path / "levers.md").read_text()
