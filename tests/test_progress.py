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
    assert table.rows() == [("stability", 1, 180.0, 180.0), ("train", 1, 360.0, 360.0)]
    assert progress.read_rule_times(work / "times.csv") == {"stability": 180.0, "train": 360.0}
    assert progress.read_rule_times(work / "none.csv") == {}
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
    log.write_text("Building DAG of jobs...\nUsing shell: /usr/bin/bash\nProvided cores: 16\n" + LOG)
    assert progress.provided_cores(log) == 16
