"""`ocpipe progress` on a run log written as Snakemake writes one."""

from datetime import datetime

import pytest

from ocpipe.bookkeeping import progress

LOG = """Building DAG of jobs...
Job stats:
job          count
---------  -------
train            2
stability        4
table            1
total            7

Select jobs to execute...
[Wed Dec  2 18:23:48 2026]
localrule train:
    input: results/features/a.zarr
    output: results/runs/a/checkpoints
    log: results/logs/train/a.log
    jobid: 1
    benchmark: results/benchmarks/train/a.tsv
    reason: Missing output files
    wildcards: exp=a
    threads: 1
[Wed Dec  2 18:23:48 2026]
localrule stability:
    log: results/logs/stability/a_run_0.log
    jobid: 2
    benchmark: results/benchmarks/stability/a_run_0.tsv
    wildcards: exp=a, run=0
[Wed Dec  2 18:30:00 2026]
Finished jobid: 1 (Rule: train)
1 of 7 steps (14%) done
[Wed Dec  2 18:30:01 2026]
localrule train:
    log: results/logs/train/b.log
    jobid: 3
    benchmark: results/benchmarks/train/b.tsv
    wildcards: exp=b
"""

BENCH = ("s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
         "{s}\t0:06:00\t1\t1\t1\t1\t0\t0\t99\t{cpu}\n")


def test_progress_names_running_jobs_their_bars_and_an_estimate_that_says_what_it_counts(tmp_path):
    (tmp_path / ".snakemake" / "log").mkdir(parents=True)
    (tmp_path / ".snakemake" / "log" / "2026-12-01T000000.snakemake.log").write_text("old run")
    (tmp_path / ".snakemake" / "log" / "2026-12-02T182344.snakemake.log").write_text(LOG)
    (tmp_path / "results" / "benchmarks" / "train").mkdir(parents=True)
    (tmp_path / "results" / "benchmarks" / "train" / "a.tsv").write_text(BENCH.format(s=370.0, cpu=360.0))
    (tmp_path / "results" / "logs" / "stability").mkdir(parents=True)
    (tmp_path / "results" / "logs" / "stability" / "a_run_0.log").write_bytes(
        b"loading\neval a:  10%|#   | 4/40 [00:20<03:00]\reval a:  12%|#   | 5/40 [00:25<02:55]\r")
    out = progress.lines(tmp_path, cores=2, now=datetime(2026, 12, 2, 19, 23, 48))
    assert out[0].endswith("1 of 7 jobs done (14%), started 1 h 00 min ago")
    assert "running or interrupted: 2" in out
    assert "  stability exp=a, run=0  |  eval a:  12%|#   | 5/40 [00:25<02:55]" in out
    assert "  train exp=b" in out  # no log file yet: no bar
    # one train job left at its finished job's 360 CPU s, on 2 cores: 3 min; stability and table have no history
    assert "left: 6 jobs; 1 of them about 3 min on 2 cores" in out[-2]
    assert out[-1].endswith("stability x4, table x1")


def _run_dir(tmp_path, log=LOG):
    (tmp_path / ".snakemake" / "log").mkdir(parents=True)
    (tmp_path / ".snakemake" / "log" / "2026-12-02T182344.snakemake.log").write_text(log)
    (tmp_path / "results" / "benchmarks" / "train").mkdir(parents=True)
    (tmp_path / "results" / "benchmarks" / "train" / "a.tsv").write_text(BENCH.format(s=370.0, cpu=360.0))
    return tmp_path


def test_rules_with_no_finished_job_are_priced_from_the_recorded_run_and_said_apart(tmp_path):
    work = _run_dir(tmp_path)
    record = work / progress.RULE_TIMES
    record.parent.mkdir(parents=True)
    # the recorded run priced train at 100 s (this run's own 360 s wins) and stability at 240 s; no table
    # a record written before kinds: rules only
    record.write_text("rule,jobs,median_cpu_seconds,cpu_seconds\ntrain,2,100.0,200.0\nstability,4,240.0,960.0\n")
    out = progress.lines(work, cores=2, now=datetime(2026, 12, 2, 19, 23, 48))
    assert "left: 6 jobs; 1 of them about 3 min on 2 cores" in out[-3]
    assert out[-2].startswith("  4 more, of rules with no finished job yet, about 8 min as the recorded run")
    assert out[-1].endswith("are not in that figure: table x1")


def test_rule_times_come_from_every_logged_job_with_a_benchmark_file(tmp_path):
    work = _run_dir(tmp_path)
    (work / "results" / "benchmarks" / "stability").mkdir()
    (work / "results" / "benchmarks" / "stability" / "a_run_0.tsv").write_text(BENCH.format(s=200.0, cpu=180.0))
    (work / "results" / "benchmarks" / "train" / "b.tsv").write_text("s\th:m:s\n")  # still being written
    table = progress.write_rule_times(work, work / "times.csv")
    assert table.rows() == [("stability", "stability exp=a", 1, 180.0, 180.0),
                            ("train", "train exp=a", 1, 360.0, 360.0)]
    assert progress.read_rule_times(work / "times.csv") == progress.Recorded(
        {"stability": 180.0, "train": 360.0}, {"stability exp=a": 180.0, "train exp=a": 360.0})
    assert progress.read_rule_times(work / "none.csv") == progress.Recorded()
    (work / ".snakemake" / "log" / "2026-12-02T182344.snakemake.log").write_text("Building DAG of jobs...\n")
    with pytest.raises(FileNotFoundError, match="no run log names a job"):
        progress.write_rule_times(work, work / "times.csv")


def test_progress_without_a_run_says_so(tmp_path):

    with pytest.raises(FileNotFoundError, match="no Snakemake run log"):
        progress.lines(tmp_path)


def test_a_log_without_its_cores_is_named(tmp_path):
    log = tmp_path / "run.snakemake.log"
    log.write_text(LOG)  # a log cut before Snakemake printed its cores
    with pytest.raises(ValueError, match="no 'Provided cores' line"):
        progress.provided_cores(log)
    log.write_text("Provided cores: 1 (use --cores to define parallelism)\n" + LOG)  # how a 1-core run says it
    assert progress.provided_cores(log) == 1
    log.write_text("Building DAG of jobs...\nUsing shell: /usr/bin/bash\nProvided cores: 16\n" + LOG)
    assert progress.provided_cores(log) == 16
    assert progress.run_cores(tmp_path) is None  # no .snakemake/log here: not known, not an error
    logs = tmp_path / ".snakemake" / "log"
    logs.mkdir(parents=True)
    (logs / "2026-12-02T000000.snakemake.log").write_text(log.read_text())
    (logs / "2026-12-03T000000.snakemake.log").write_text(LOG)  # a later dry run or report: no core count
    assert progress.run_cores(tmp_path) == 16


def test_a_jobs_kind_is_its_rule_and_wildcards_less_replicate_shard_run_and_checkpoint():
    kind = lambda rule, wildcards: progress.Job(rule, 1, None, wildcards).kind  # noqa: E731
    assert kind("stability", "exp=goal2d@3, run=0") == "stability exp=goal2d"
    assert kind("sweep", "exp=goal2d@3, epoch=16") == "sweep exp=goal2d"
    assert kind("frames_shard", "task=PickCube-v1, cams=dual, res=128, shard=1") == \
        "frames_shard task=PickCube-v1, cams=dual, res=128"
    assert kind("lever_eval", "lever=goal2d_goal_relative@2") == "lever_eval lever=goal2d_goal_relative"
    assert kind("table", "") == "table"


FINISHED_LOG = """Building DAG of jobs...
Job stats:
job      count
-----  -------
train        4
total        4

[Wed Dec  2 18:00:00 2026]
localrule train:
    jobid: 1
    benchmark: results/benchmarks/train/ctl@0.tsv
    wildcards: exp=ctl@0
[Wed Dec  2 18:00:00 2026]
localrule train:
    jobid: 2
    benchmark: results/benchmarks/train/a@0.tsv
    wildcards: exp=a@0
[Wed Dec  2 18:01:00 2026]
Finished jobid: 1 (Rule: train)
1 of 4 steps (25%) done
[Wed Dec  2 18:01:00 2026]
localrule train:
    jobid: 3
    benchmark: results/benchmarks/train/a@1.tsv
    wildcards: exp=a@1
[Wed Dec  2 18:06:00 2026]
Finished jobid: 2 (Rule: train)
2 of 4 steps (50%) done
[Wed Dec  2 18:06:00 2026]
localrule train:
    jobid: 4
    benchmark: results/benchmarks/train/b@0.tsv
    wildcards: exp=b@0
[Wed Dec  2 18:07:00 2026]
Finished jobid: 3 (Rule: train)
3 of 4 steps (75%) done
[Wed Dec  2 18:16:00 2026]
Finished jobid: 4 (Rule: train)
4 of 4 steps (100%) done
"""


def _finished_run(tmp_path):
    """FINISHED_LOG's run in ``tmp_path``: its log and the benchmark files of its four trainings."""
    bench = tmp_path / "results" / "benchmarks" / "train"
    bench.mkdir(parents=True)
    for name, cpu in (("ctl@0", 60.0), ("a@0", 300.0), ("a@1", 300.0), ("b@0", 600.0)):
        (bench / f"{name}.tsv").write_text(BENCH.format(s=cpu, cpu=cpu))
    log = tmp_path / "run.snakemake.log"
    log.write_text(FINISHED_LOG)
    return log


def test_jobs_are_priced_by_their_kind_then_the_records_kind_then_their_rule(tmp_path):
    log = _finished_run(tmp_path)
    run = progress.parse(log)
    assert run.finished_at[4] == datetime(2026, 12, 2, 18, 16)
    pending = [run.jobs[3], run.jobs[4]]  # a@1 and b@0, with ctl@0 and a@0 finished
    done = {1: 60.0, 2: 300.0}
    # a@1 at its kind's 300 s; b@0 has no kind here and no record: the rule's median of 60 and 300, 180 s
    est = progress.estimate(run, 1, done, None, pending)
    assert (est.seconds, est.by_kind, est.by_recorded_kind) == (300.0 + 180.0, 1, 0)
    # a record that had b at 400 s and a at 150 s: this run is twice as slow (300 / 150), so b costs 800 s
    record = progress.Recorded({"train": 200.0}, {"train exp=a": 150.0, "train exp=b": 400.0})
    est = progress.estimate(run, 1, done, record, pending)
    assert (est.speed, est.seconds, est.by_kind, est.by_recorded_kind) == (2.0, 300.0 + 800.0, 1, 1)
    # on 2 cores, the same work in half the time
    assert progress.estimate(run, 2, done, record, pending).seconds == (300.0 + 800.0) / 2


def test_replay_sets_each_estimate_beside_the_time_the_run_really_went_on(tmp_path):
    log = _finished_run(tmp_path)
    t = progress.replay(progress.parse(log), tmp_path, 1, shares=(0.25, 0.5))
    # at 1 of 4 jobs (18:01): a@0, a@1, b@0 left, each at the control's 60 s by rule and kind alike; 15 min to go
    # at 2 of 4 (18:06): a@1 at a's 300 s by kind (b at the rule's median, 180 s), 180 s each by rule; 10 min left
    # one core, and a job running beside every finished one: utilisation 1 (capped), so no change
    assert t.columns == ["share", "jobs_done", "estimate_by_rule_min", "estimate_by_kind_min", "utilisation_so_far",
                         "estimate_by_kind_at_utilisation_min", "actual_min", "jobs_unpriced"]
    assert t.rows() == [(0.25, 1, 3.0, 3.0, 1.0, 3.0, 15.0, 0), (0.5, 2, 6.0, 8.0, 1.0, 8.0, 10.0, 0)]
    log.write_text(FINISHED_LOG.rsplit("[Wed Dec  2 18:16:00 2026]", 1)[0])  # b@0 still running
    with pytest.raises(ValueError, match="not a finished run"):
        progress.replay(progress.parse(log), tmp_path, 1)


def test_the_jobs_to_come_are_listed_by_a_dry_run_of_the_runs_own_command(tmp_path):
    fake = tmp_path / "snakemake"  # prints what `snakemake -n` prints, and the arguments it was given
    fake.write_text("#!/bin/sh\necho \"args: $*\" > args.txt\ncat <<'EOF'\n" + LOG.split("[Wed Dec  2 18:30:00")[0]
                    + "EOF\n")
    fake.chmod(0o755)
    run = progress.parse_text(f"Command: {fake} --cores 2 -- results/tables/table5_1.csv\n")
    jobs = progress.plan(run, tmp_path)
    assert [(j.rule, j.kind) for j in jobs] == [("train", "train exp=a"), ("stability", "stability exp=a")]
    # exact: the arguments the fake wrote back, as text
    assert (tmp_path / "args.txt").read_text() == "args: -n --nolock --cores 2 -- results/tables/table5_1.csv\n"
    fake.write_text("#!/bin/sh\nexit 1\n")  # a dry run that fails: no list, and the estimate falls back to rules
    assert progress.plan(run, tmp_path) is None
    assert progress.plan(progress.parse_text("no command line here\n"), tmp_path) is None


def test_utilisation_so_far_counts_finished_jobs_and_running_ones_at_the_finished_ones_pace(tmp_path):
    run = progress.parse(_finished_run(tmp_path))
    # at 18:06 on 2 cores: ctl@0 (60 s) and a@0 (300 s) finished, each CPU = wall; a@1 has run 300 s, b@0 0 s
    times = {1: (60.0, 60.0), 2: (300.0, 300.0)}
    seen = progress.Run(run.log, run.started, run.planned, run.jobs, {1, 2})
    busy = progress.utilisation_so_far(seen, times, datetime(2026, 12, 2, 18, 6), cores=2)
    assert busy == pytest.approx((60 + 300 + 300) / (2 * 360))  # derived: float division of whole seconds
    # a finished job that used half its wall time puts the running ones at half pace too
    half = progress.utilisation_so_far(seen, {1: (60.0, 30.0), 2: (300.0, 150.0)}, datetime(2026, 12, 2, 18, 6), 2)
    assert half == pytest.approx((30 + 150 + 0.5 * 300) / (2 * 360))  # derived: as above
    assert progress.utilisation_so_far(seen, {}, datetime(2026, 12, 2, 18, 6), 2) is None  # nothing finished yet


def test_a_jobs_threads_inputs_and_outputs_are_read_and_default_to_one_thread_and_none():
    run = progress.parse_text(LOG)
    train, stability = run.jobs[1], run.jobs[2]
    assert (train.threads, train.inputs, train.outputs) == (1, ("results/features/a.zarr",),
                                                            ("results/runs/a/checkpoints",))
    assert (stability.threads, stability.inputs, stability.outputs) == (1, (), ())
    two = progress.parse_text("[Sun Dec  6 20:05:10 2026]\nlocalrule features:\n"
                              "    input: results/frames/s.zarr, results/encoders/slots_ssl/model.pt\n"
                              "    output: results/features/s.zarr\n    jobid: 4\n    threads: 2\n")
    assert (two.jobs[4].threads, two.jobs[4].inputs) == (2, ("results/frames/s.zarr",
                                                             "results/encoders/slots_ssl/model.pt"))
    assert two.last_at == datetime(2026, 12, 6, 20, 5, 10)


def _job(time, rule, jobid, inputs="", outputs="", threads=1, wildcards=""):
    """A job's start as Snakemake logs it."""
    fields = {"input": inputs, "output": outputs, "jobid": jobid, "wildcards": wildcards, "threads": threads}
    return f"[{time}]\nlocalrule {rule}:\n" + "".join(f"    {k}: {v}\n" for k, v in fields.items() if v)


def _done(time, rule, jobid):
    return f"[{time}]\nFinished jobid: {jobid} (Rule: {rule})\n"


# on 2 cores: frames (1 thread) makes a.zarr by 10:01:00 while scenes (1 thread) runs to 10:04:00; features x and y
# (2 threads each) need a.zarr, so both are ready at 10:01:00 and wait with one core idle until scenes finishes
WAITING_LOG = ("Provided cores: 2\n"
               + _job("Sun Dec  6 10:00:00 2026", "frames", 1, outputs="results/frames/a.zarr")
               + _job("Sun Dec  6 10:00:00 2026", "scenes", 2, inputs="results/demos/old.h5",
                      outputs="results/scenes/b.zarr")
               + _done("Sun Dec  6 10:01:00 2026", "frames", 1)
               + _done("Sun Dec  6 10:04:00 2026", "scenes", 2)
               + _job("Sun Dec  6 10:04:00 2026", "features", 3, "results/frames/a.zarr, results/encoders/m.pt",
                      "results/features/x.zarr", 2, "store=x")
               + _done("Sun Dec  6 10:06:00 2026", "features", 3)
               + _job("Sun Dec  6 10:06:00 2026", "features", 4, "results/frames/a.zarr", "results/features/y.zarr",
                      2, "store=y")
               + _done("Sun Dec  6 10:08:00 2026", "features", 4))


def test_a_two_thread_job_ready_while_one_core_idles_is_charged_the_idle_core_time():
    waits = progress.idle_waits(progress.parse_text(WAITING_LOG), cores=2)
    # x: ready 10:01:00, started 10:04:00; scenes held one core of two all along: 1 idle core x 180 s
    # y: ready 10:01:00, started 10:06:00; the same 180 s, then x held both cores (10:04-10:06): nothing idle
    assert waits.jobs == [progress.Wait("features store=x", 180.0, 180.0),
                          progress.Wait("features store=y", 300.0, 180.0)]
    assert waits.wide_jobs == 2
    assert waits.core_seconds == 180.0  # x and y waited through the same idle core: counted once, not 360


def test_a_two_thread_job_that_starts_when_ready_waits_for_nothing():
    # its input was made before this run (no job here outputs old.zarr): ready at the run's start, and started
    # then; the 1-thread scenes job after it is not one the rule is about
    log = ("Provided cores: 2\n"
           + _job("Sun Dec  6 10:00:00 2026", "features", 1, "results/frames/old.zarr", "results/features/x.zarr", 2)
           + _done("Sun Dec  6 10:02:00 2026", "features", 1)
           + _job("Sun Dec  6 10:02:00 2026", "scenes", 2, "results/features/x.zarr", "results/scenes/x.zarr")
           + _done("Sun Dec  6 10:03:00 2026", "scenes", 2))
    waits = progress.idle_waits(progress.parse_text(log), cores=2)
    assert (waits.core_seconds, waits.jobs, waits.wide_jobs) == (0.0, [], 1)


def test_a_job_with_no_finish_holds_its_core_to_the_logs_last_timestamp():
    # on 3 cores, train (1 thread) never finishes in this cut-off log; features (2 threads) is ready at 10:01:00 and
    # starts at 10:02:00: train holds one core, so 2 idle cores x 60 s (3 x 60 if train were taken as gone)
    log = ("Provided cores: 3\n"
           + _job("Sun Dec  6 10:00:00 2026", "frames", 1, outputs="results/frames/a.zarr")
           + _job("Sun Dec  6 10:00:00 2026", "train", 2, outputs="results/runs/t")
           + _done("Sun Dec  6 10:01:00 2026", "frames", 1)
           + _job("Sun Dec  6 10:02:00 2026", "features", 3, "results/frames/a.zarr", "results/features/a.zarr", 2)
           + _done("Sun Dec  6 10:03:00 2026", "features", 3))
    run = progress.parse_text(log)
    assert run.last_at == datetime(2026, 12, 6, 10, 3)
    assert progress.idle_waits(run, cores=3).core_seconds == 120.0


def test_the_log_with_the_cores_is_the_newest_that_names_them(tmp_path):
    assert progress.cores_log(tmp_path) is None
    logs = tmp_path / ".snakemake" / "log"
    logs.mkdir(parents=True)
    (logs / "2026-12-06T100000.snakemake.log").write_text(WAITING_LOG)
    (logs / "2026-12-07T100000.snakemake.log").write_text(LOG)  # a later dry run: no core count
    assert progress.cores_log(tmp_path) == (logs / "2026-12-06T100000.snakemake.log", 2)
