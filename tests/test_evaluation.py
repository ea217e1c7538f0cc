import numpy as np
import polars as pl
import pytest
from tolerances import EPS32

from ocpipe.config.errors import ConfigError
from ocpipe.config.validate import validate
from ocpipe.evaluation import closed_loop, jobs, taxonomy
from ocpipe.evaluation.best import best_checkpoint
from ocpipe.stats import pooled
from ocpipe.study import inputs, registry, report, tables

RULES = {"idle_variance": 0.001, "near_miss_m": 0.10, "stack_near_m": 0.10, "lift_m": 0.02}


def steps(n=20, grasped=None, tcp_goal=0.5, action_scale=1.0, lift=0.0, obj_goal=0.5, seed=0):
    """A synthetic per-step log: goal at the origin, TCP at distance tcp_goal, cube at obj_goal (lifted by lift)."""
    rng = np.random.default_rng(seed)
    grasped = [False] * n if grasped is None else grasped
    obj = [[obj_goal, 0.0, 0.02 + (lift if g else 0.0)] for g in grasped]
    return pl.DataFrame(
        {
            "step": list(range(n)),
            "action": (rng.normal(0, action_scale, (n, 8))).tolist(),
            "is_grasped": grasped,
            "tcp_pos": [[tcp_goal, 0.0, 0.0]] * n,
            "goal_pos": [[0.0, 0.0, 0.0]] * n,
            "obj_pos": obj,
        }
    )


@pytest.mark.parametrize(
    "log,success,task,expected",
    [
        (steps(), True, "PickCube-v1", "Success"),
        (steps(action_scale=0.01), False, "PickCube-v1", "Idle"),
        (steps(), False, "PickCube-v1", "No Grasp"),
        (steps(grasped=[False] * 5 + [True] * 10 + [False] * 5), False, "PickCube-v1", "Drop"),
        (steps(grasped=[False] * 5 + [True] * 15, tcp_goal=0.05), False, "PickCube-v1", "Near Miss"),
        (steps(grasped=[False] * 5 + [True] * 15, tcp_goal=0.5), False, "PickCube-v1", "Unknown"),
        (steps(grasped=[False] * 5 + [True] * 15, lift=0.05, obj_goal=0.3), False, "StackCube-v1", "Grasp No Stack"),
        (
            steps(grasped=[False] * 5 + [True] * 15, lift=0.05, obj_goal=0.05, tcp_goal=0.05),
            False,
            "StackCube-v1",
            "Near Miss",
        ),
        # Grasp No Stack is StackCube's own class: on PickCube the same log is a Near Miss or Unknown
        (steps(grasped=[False] * 5 + [True] * 15, lift=0.05, obj_goal=0.3), False, "PickCube-v1", "Unknown"),
    ],
)
def test_every_taxonomy_branch(log, success, task, expected):
    assert taxonomy.classify(log, success, task, RULES) == expected


def test_first_matching_rule_wins():
    # successful but idle-looking and never grasped: Success comes first
    assert taxonomy.classify(steps(action_scale=0.0), True, "PickCube-v1", RULES) == "Success"
    # idle and never grasped: Idle before No Grasp
    assert taxonomy.classify(steps(action_scale=0.0), False, "PickCube-v1", RULES) == "Idle"


def test_stackcube_funnel_counts_stages_in_order():
    g = [False] * 5 + [True] * 15
    logs = {
        1: steps(),
        2: steps(grasped=g),
        3: steps(grasped=g, lift=0.05),
        4: steps(grasped=g, lift=0.05, obj_goal=0.05),
        5: steps(grasped=g, lift=0.05, obj_goal=0.05),
    }
    eps = pl.DataFrame({"seed": list(logs), "success": [False, False, False, False, True], "trivial": [False] * 5})
    all_steps = pl.concat([log.with_columns(pl.lit(s).alias("seed")) for s, log in logs.items()])
    classes = taxonomy.classify_run(eps, all_steps, "StackCube-v1", RULES)
    assert taxonomy.funnel(classes) == {"episodes": 5, "grasp": 4, "lift": 3, "near target": 2, "success": 1}
    assert classes["class"].to_list() == ["No Grasp", "Unknown", "Grasp No Stack", "Unknown", "Success"]


EVAL = {
    "seed_pool_start": 10000,
    "seed_pool_size": 1000,
    "validation_pool_size": 200,
    "sweep_episodes": 20,
    "stability_runs": 3,
    "stability_episodes": 30,
    "failure_episodes": 200,
    "training_time_episodes": 30,
}


def test_table_jobs_draw_disjoint_blocks_of_the_test_pool_the_same_for_every_experiment():
    a = jobs.seeds_for("stability", EVAL, 0, run=1)
    assert a == jobs.seeds_for("stability", EVAL, 0, run=1)
    assert a != jobs.seeds_for("stability", EVAL, 1, run=1)  # the root seed reshuffles the pool
    draws = [jobs.seeds_for("sweep", EVAL, 0), *(jobs.seeds_for("stability", EVAL, 0, run=r) for r in range(3)),
             jobs.seeds_for("failure_run", EVAL, 0), jobs.seeds_for("training_time", EVAL, 0)]
    assert [len(d) for d in draws] == [20, 30, 30, 30, 200, 30]
    every = [s for d in draws for s in d]
    assert len(set(every)) == len(every)  # pairwise disjoint
    assert min(every) >= 10200 and max(every) < 11000  # the test pool: the validation pool's 200 seeds come first
    with pytest.raises(ValueError, match="stability run 3"):
        jobs.seeds_for("stability", EVAL, 0, run=3)


def test_validation_seeds_never_meet_the_test_pool():
    val = jobs.validation_seeds(EVAL, 100, 0)
    assert len(set(val)) == 100 and min(val) >= 10000 and max(val) < 10200
    assert set(jobs.validation_seeds(EVAL, 10, 0)) <= set(val)  # a prefix of one shuffle
    with pytest.raises(ValueError, match="validation_pool_size is 200"):
        jobs.validation_seeds(EVAL, 201, 0)


def test_the_training_time_block_comes_last_so_the_other_blocks_keep_their_seeds():
    without = {**EVAL, "training_time_episodes": 0}
    for kind, run in (("sweep", 0), ("stability", 2), ("failure_run", 0)):
        assert jobs.seeds_for(kind, EVAL, 0, run=run) == jobs.seeds_for(kind, without, 0, run=run)


def test_a_test_pool_too_small_for_the_table_jobs_is_named():
    small = {**EVAL, "seed_pool_size": 400}  # 200 validation + 200 test < 20 + 90 + 200 + 30
    with pytest.raises(ValueError, match="draw 340 disjoint seeds but the test pool"):
        jobs.seeds_for("sweep", small, 0)


def test_tables_refuse_a_diagnostic_readout_filter(default_config):
    default_config["evaluation"]["readout_filter"] = "true_pose"
    with pytest.raises(ConfigError, match="readout_filter: 'true_pose' is a diagnostic"):
        validate(default_config)


def test_demo_seeds_may_not_reach_into_the_evaluation_pool(default_config):
    default_config["demos"]["seed_start"] = 9900
    with pytest.raises(ConfigError, match="demos.seed_start"):
        validate(default_config)


def test_tables_name_defined_experiments(default_config):
    default_config["tables"]["table5_1"]["Oracle"] = "no_such_exp"
    with pytest.raises(ConfigError, match="tables.table5_1.Oracle: experiment 'no_such_exp'"):
        validate(default_config)


def episodes(run, successes, steps_, trivial=None):
    n = len(successes)
    return pl.DataFrame(
        {
            "exp": ["e"] * n,
            "checkpoint": [10] * n,
            "run": [run] * n,
            "seed": list(range(n)),
            "success": successes,
            "steps": steps_,
            "trivial": trivial or [False] * n,
            "return": [1.0] * n,
        }
    )


def test_trivial_successes_count_in_neither_numerator_nor_total():
    eps = episodes(0, [True, True, False, False], [5, 50, 100, 100], trivial=[True, False, False, False])
    # exact: one division of integer counts, 1 / 3 on both sides; approx only because 1/3 has no finite binary form
    assert pooled.success_rate(eps) == pytest.approx(1 / 3)


def test_table5_1_from_known_rows():
    runs = pl.concat(
        [
            episodes(0, [True, False], [40, 100]),
            episodes(1, [True, True], [40, 60]),
            episodes(2, [False, False, True], [100, 100, 4], trivial=[False, False, True]),
        ]
    )
    t = tables.build(registry.TABLES["table5_1"].columns, [tables.Row("2D", {}, {inputs.STABILITY: runs})])
    row = t.row(0, named=True)
    assert row["SR mean"] == pytest.approx(0.5)  # exact: runs 0.5, 1.0, 0.0 are dyadic, so their mean is exact
    assert row["SR std"] == pytest.approx(0.5)  # exact: sample std of (0.5, 1, 0) is sqrt(0.5 / 2), all dyadic
    # exact: integer run means 70, 50, 100, summed exactly, then one division by 3, as here; approx only for the /3
    assert row["Episode length mean"] == pytest.approx((70 + 50 + 100) / 3)
    assert row["Runs"] == 3 and row["Trivial excluded"] == 1


def test_a_table_refuses_a_policys_episodes_of_two_checkpoints():
    """A stability run is the best checkpoint's alone; episodes of two checkpoints (a stability rule that ran the
    sweep's) are named, not pooled into a row."""
    two = pl.concat([episodes(0, [True, False], [40, 100]),
                     episodes(0, [False, False], [100, 100]).with_columns(checkpoint=pl.lit(5, pl.Int64))])
    with pytest.raises(ValueError, match=r"e: its episodes hold checkpoints \[5, 10\]"):
        tables.stability_summary(two)


@pytest.mark.parametrize("kind,epochs,best,problem", [
    ("stability", [8, 16], "best.json", "a stability job of goal2d runs its best checkpoint alone"),
    ("failure_run", None, None, "a failure_run job of goal2d runs its best checkpoint alone"),
    ("sweep", None, None, "a sweep job of goal2d needs the checkpoints it runs"),
])
def test_only_a_sweep_or_a_lever_runs_the_checkpoints_it_is_given(tmp_path, kind, epochs, best, problem):
    """Each evaluation kind runs what it is for (a sweep every checkpoint, a stability run the best one): a job
    given the other is refused before anything is built."""
    with pytest.raises(ValueError, match=problem):
        jobs.run_job(kind, "goal2d", {}, tmp_path, tmp_path, None, tmp_path / "e.parquet", tmp_path / "s.parquet",
                     0, best_json=best and tmp_path / best, epochs=epochs, progress=False)
    assert not list(tmp_path.iterdir())


def test_table5_2_counts_and_percentages(tmp_path):
    classes = pl.DataFrame(
        {"class": ["Success", "Drop", "Drop", "No Grasp", "Success"], "trivial": [False, False, False, False, True]}
    )
    t = tables.table5_2({"Pure": classes}).row(0, named=True)
    assert (t["Success"], t["Drop"], t["No Grasp"], t["Near Miss"], t["Total"]) == (1, 2, 1, 0, 4)
    assert t["Drop %"] == pytest.approx(50.0)  # exact: 100 * 2 / 4 on integers


def sweep_files(tmp_path, results):
    """One sweep file per (epoch, successes, episodes, mean return)."""
    files = []
    for epoch, k, n, ret in results:
        f = tmp_path / f"epoch_{epoch}.episodes.parquet"
        episodes(0, [True] * k + [False] * (n - k), [50] * n).with_columns(
            pl.lit(epoch).alias("checkpoint"), pl.lit(ret).alias("return")
        ).write_parquet(f)
        files.append(f)
    return files


def test_best_checkpoint_takes_the_sweep_leader_only_where_fisher_resolves_it(tmp_path):
    log = tmp_path / "train_log.parquet"
    pl.DataFrame({"epoch": [8, 16], "val_joint_err_rad": [0.0119, 0.0108]}).write_parquet(log)
    # 3/6 against 1/6 (one-sided p = 0.27): the lower open-loop error decides
    best = best_checkpoint(sweep_files(tmp_path, ((8, 3, 6, 1.0), (16, 1, 6, 1.0))), log)
    assert (best["epoch"], best["chosen_by"]) == (16, "open-loop error")
    # derived: p = P(X >= 3), X hypergeometric = (224 + 28) / 924 = 3/11, two pmf terms scipy evaluates in float64
    # (error ~1e-15); approx's 1e-6 default covers it and is far below the gap to a one-count change of p (> 0.1)
    assert best["sweep_p"] == pytest.approx(3 / 11)
    sweep = {r["checkpoint"]: r for r in best["sweep"]}
    assert (sweep[8]["successes"], sweep[8]["episodes"], sweep[16]["val_joint_err_rad"]) == (3, 6, 0.0108)
    # 15/20 against 3/20 resolves it
    best = best_checkpoint(sweep_files(tmp_path, ((8, 15, 20, 1.0), (16, 3, 20, 1.0))), log)
    assert (best["epoch"], best["chosen_by"]) == (8, "sweep SR") and best["sweep_p"] < 0.05
    # alpha is the caller's: at 0.5 the 3/6 leader is taken
    assert best_checkpoint(sweep_files(tmp_path, ((8, 3, 6, 1.0), (16, 1, 6, 1.0))), log, alpha=0.5)["epoch"] == 8


def test_best_checkpoint_without_open_loop_error_falls_back_to_return_then_epoch(tmp_path):
    files = sweep_files(tmp_path, ((10, 1, 2, 3.0), (20, 1, 2, 5.0), (30, 0, 2, 9.0)))
    assert best_checkpoint(files)["epoch"] == 30
    files = sweep_files(tmp_path, ((10, 1, 2, 5.0), (20, 1, 2, 5.0)))
    assert best_checkpoint(files)["epoch"] == 20


def test_report_writes_tables_from_run_files(tmp_path, one_policy_config):
    runs = tmp_path / "runs"
    for exp, succ in (("a", [True, False]), ("b", [True, True])):
        (runs / exp / "stability").mkdir(parents=True)
        for r in range(2):
            episodes(r, succ, [50, 80]).write_parquet(runs / exp / "stability" / f"run_{r}.episodes.parquet")
    config = {
        **one_policy_config,
        "experiments": {"a": {}, "b": {}},
        "tables": {"table5_1": {"A": "a", "B": "b"}},
        "evaluation": {**one_policy_config["evaluation"], "stability_runs": 2},
    }
    t = report.write_table(config, "table5_1", tmp_path / "t.csv", tmp_path / "t.md", runs_dir=runs)
    assert t["SR mean"].to_list() == [0.5, 1.0]
    assert pl.read_csv(tmp_path / "t.csv")["Method"].to_list() == ["A", "B"]
    assert "| A |" in (tmp_path / "t.md").read_text()


def test_a_new_table_is_one_registry_entry(tmp_path, one_policy_config, monkeypatch):
    from ocpipe.config.errors import ConfigError
    from ocpipe.config.validate import validate
    from ocpipe.study import findings

    runs = tmp_path / "runs"
    for exp, succ in (("a", [True, False]), ("b", [False, False])):
        (runs / exp / "stability").mkdir(parents=True)
        for r in range(2):
            episodes(r, succ, [50, 80]).write_parquet(runs / exp / "stability" / f"run_{r}.episodes.parquet")
    config = {
        **one_policy_config,
        "experiments": {**one_policy_config["experiments"], "a": {"visual_dropout": 0.0},
                        "b": {"visual_dropout": 0.3}},
        "tables": {**one_policy_config["tables"], "table_dropout": {"none": "a", "0.3": "b"}},
        "evaluation": {**one_policy_config["evaluation"], "stability_runs": 2},
    }
    validate(config)  # the schema leaves table names to the registry
    with pytest.raises(ConfigError, match="tables.table_dropout: not a table of the study"):
        findings.check_config(config)
    monkeypatch.setitem(registry.TABLES, "table_dropout", registry.Table(
        "Dropout", (inputs.STABILITY,), "ablations", tables.setting_columns("Dropout", "visual_dropout"),
        varies=("visual_dropout",)))
    findings.check_config(config)
    assert "table_dropout" in registry.tables_in("ablations")
    t = report.write_table(config, "table_dropout", tmp_path / "t.csv", tmp_path / "t.md", runs_dir=runs)
    assert t["Dropout"].to_list() == [0.0, 0.3] and t["SR mean"].to_list() == [0.5, 0.0]
    assert (tmp_path / "t.md").read_text().startswith("**Dropout**")


def test_temporal_ensemble_weights_older_chunks_more_and_votes_the_gripper():
    from collections import deque

    from ocpipe.evaluation.closed_loop import ensemble_action

    old = np.zeros((4, 8), np.float32)
    old[:, 7] = 1.0
    new = np.ones((4, 8), np.float32)
    new[:, 7] = -1.0
    chunks = deque([(0, old), (2, new)])
    # step 1: only the old chunk covers it
    np.testing.assert_array_equal(ensemble_action(chunks, 1, 0.5), old[1])  # exact: one chunk at weight exp(0) = 1
    # step 2: both; joints at exp(-0.5) / (1 + exp(-0.5)) of the way to the new chunk, the old gripper vote wins
    a = ensemble_action(chunks, 2, 0.5)
    # derived: the product's float64 weighted mean (4 ops, ~1e-16) is cast to float32: at most half a float32 ulp
    np.testing.assert_allclose(a[:7], np.exp(-0.5) / (1 + np.exp(-0.5)), rtol=EPS32)
    assert a[7] == 1.0
    # step 5: the old chunk (4 steps from 0) no longer covers it
    np.testing.assert_array_equal(ensemble_action(chunks, 5, 0.5), new[3])  # exact: one chunk at weight 1


@pytest.mark.parametrize("exp, reads_labels, expected", [
    ("head_flatten", False, ["base"]),                 # reads the base camera's slots only
    ("pure_visual", False, ["base", "side"]),
    ("goal2d_exact", False, ["base", "side"]),         # reads both anyway
    ("state_control", True, []),                       # its tokens are the simulator's state
    ("stack_native", False, ["base", "hand"]),
])
def test_the_closed_loop_renders_only_the_cameras_a_step_needs(default_config, exp, reads_labels, expected):
    from ocpipe.config import experiments
    from ocpipe.policy.settings import PolicySettings

    policy = PolicySettings.of(experiments.resolve(default_config, exp))
    assert closed_loop.cameras_to_render(policy, reads_labels) == expected
    one_camera_exact = PolicySettings.of({**experiments.resolve(default_config, "goal2d_exact"), "cameras": [1]})
    assert closed_loop.cameras_to_render(one_camera_exact, False) == ["base", "side"]  # live matrices of both
    assert closed_loop.cameras_to_render(PolicySettings.of({**experiments.resolve(default_config, "goal2d"),
                                                            "cameras": [1]}), False) == ["side"]
