"""The compute table: benchmark files charged to the experiment, store or table that built them."""

import os
import re
import subprocess
import sys

import polars as pl
import pytest
from conftest import REPO
from tolerances import reduction_atol

from ocpipe.bookkeeping import compute

HEADER = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"


def _bench(root, rel, seconds, cpu, end):
    f = root / rel
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_text(HEADER + f"{seconds}\t0:00:00\t1\t1\t1\t1\t0\t0\t100\t{cpu}\n")
    os.utime(f, (end, end))


@pytest.fixture
def bench(tmp_path):
    b = tmp_path / "benchmarks"
    t0 = 1_000_000.0
    _bench(b, "demos_shard/PickCube-v1_shard0.tsv", 60, 60, t0 + 60)
    _bench(b, "frames_shard/PickCube-v1_dual_128_shard0.tsv", 120, 90, t0 + 180)
    _bench(b, "frames_shard/PickCube-v1_dual_128_shard1.tsv", 120, 90, t0 + 180)
    _bench(b, "train_slots_ssl.tsv", 600, 600, t0 + 780)
    _bench(b, "features/PickCube-v1_dual_128_slots_ssl.tsv", 120, 180, t0 + 900)
    for exp, train in (("pure_visual", 300), ("goal2d", 240)):
        _bench(b, f"train/{exp}.tsv", train, train, t0 + 1200)
        for e in ("0008", "0016"):
            _bench(b, f"sweep/{exp}_epoch_{e}.tsv", 30, 30, t0 + 1300)
        for r in range(3):
            _bench(b, f"stability/{exp}_run_{r}.tsv", 120, 120, t0 + 1700)
    _bench(b, "train/weight_time.tsv", 180, 180, t0 + 1900)
    _bench(b, "tables/table5_1.tsv", 6, 6, t0 + 1800)
    _bench(b, "tables/table5_9.tsv", 6, 6, t0 + 2000)
    return b


def test_jobs_are_charged_to_what_they_built(bench):
    rows = compute.charged(compute.read_jobs(bench)).iter_rows(named=True)
    by = {(r["kind"], r["what"], r["stage"]): r for r in rows}
    assert by[("experiment", "goal2d", "stability")]["jobs"] == 3
    assert by[("experiment", "goal2d", "stability")]["core_min"] == 6.0
    assert by[("experiment", "pure_visual", "sweep")]["core_min"] == 1.0
    assert by[("store", "PickCube-v1_dual_128", "frames")] == {
        "kind": "store", "what": "PickCube-v1_dual_128", "stage": "frames", "jobs": 2, "job_min": 4.0, "core_min": 3.0}
    assert by[("encoder", "slots_ssl", "encoder")]["core_min"] == 10.0
    assert by[("store", "PickCube-v1", "demos")]["job_min"] == 1.0
    assert by[("table", "table5_1", "report")]["core_min"] == 0.1


def test_tables_add_what_they_build_first_and_sum_to_the_run(default_config, bench):
    jobs = compute.read_jobs(bench)
    totals = compute.charged(jobs).group_by("kind", "what").agg(pl.col("job_min", "core_min").sum())
    adds = dict(compute.per_table(default_config, totals).select("table", "core_min").iter_rows())
    # every job's CPU seconds are a multiple of 6, so every figure below is a whole number of tenths of a minute
    # table 5.1 builds the stores, the encoder, pure_visual and goal2d (state_control and goal3d never ran here)
    # exact: per_table rounds to 0.1 min; approx only because a tenth has no finite binary form
    assert adds["table5_1"] == pytest.approx(1 + 3 + 10 + 3 + (5 + 1 + 6) + (4 + 1 + 6) + 0.1)
    assert adds["table5_2"] == 0.0  # the same rows: nothing new to build
    # exact: weight_time's training and the table itself, in tenths; approx only because 0.1 is not binary
    assert adds["table5_9"] == pytest.approx(3 + 0.1)
    # exact: whole tenths on both sides (2592 s = 43.2 min); approx only because tenths are not binary
    assert sum(adds.values()) == pytest.approx(jobs["cpu_seconds"].sum() / 60)


def test_wall_time_spans_first_start_to_last_end(bench):
    # exact: the span is 2000.0 s of whole-second mtimes, and the product rounds it to 0.1 min with this same round
    assert compute.wall_minutes(compute.read_jobs(bench)) == round(2000 / 60, 1)


def test_write_names_the_run_and_an_empty_folder_is_an_error(default_config, bench, tmp_path):
    compute.write(default_config, bench, tmp_path / "c.csv", tmp_path / "c.md", cores=2, workdir=tmp_path)
    text = (tmp_path / "c.md").read_text()
    assert "| goal2d |" in text and "wall time 33.3 min" in text
    # 43.2 core-minutes in 33.3 wall minutes (rounded as printed) on 2 cores: 43.2 / 66.6 = 64.9 %
    assert "utilisation 65 % of 2 cores" in text
    compute.write(default_config, bench, tmp_path / "c.csv", tmp_path / "c.md", cores=None,  # a cluster run
                  workdir=tmp_path)
    assert "utilisation not known" in (tmp_path / "c.md").read_text()
    core = pl.read_csv(tmp_path / "c.csv")["core_min"]
    # derived: each row is a whole tenth (CPU seconds in multiples of 6) written to 4 decimals, so the CSV sum differs
    # from the total only by float64 round-off of a sum of len(core) terms of at most max(core) minutes
    assert core.sum() == pytest.approx(compute.read_jobs(bench)["cpu_seconds"].sum() / 60,
                                       abs=reduction_atol(len(core), core.max()))
    with pytest.raises(FileNotFoundError, match="no benchmark files"):
        compute.read_jobs(tmp_path / "nothing")


def test_record_copies_a_whole_runs_tables_and_refuses_part_of_one(default_config, tmp_path):
    from ocpipe.bookkeeping import record

    tables = tmp_path / "results" / "tables"
    tables.mkdir(parents=True)
    names = [*default_config["tables"], "findings", "compute"]
    for n in names:
        (tables / f"{n}.csv").write_text(f"{n},1\n")
        (tables / f"{n}.md").write_text(f"**{n}**\n")
    out = tmp_path / "docs" / "results"
    out.mkdir(parents=True)
    (out / "table5_99.csv").write_text("stale")
    files = record.write(default_config, tmp_path / "results", out, "time snakemake --cores 2 all", "abc123")
    assert len(files) == 2 * len(names)
    assert (out / "table5_3.csv").read_text() == "table5_3,1\n"  # exact: a copied file
    assert not (out / "table5_99.csv").exists()  # a table of an older run does not survive into this record
    assert "Commit `abc123`" in (out / "README.md").read_text()
    assert not (out / "rule_times.csv").exists()  # no run log beside the results: no rule times
    assert "as the run's compute job wrote it" in (out / "README.md").read_text()  # no benchmark files: a copy
    log = tmp_path / ".snakemake" / "log" / "2026-12-03T000000.snakemake.log"
    log.parent.mkdir(parents=True)
    log.write_text("[Thu Dec  3 00:00:00 2026]\nlocalrule train:\n    jobid: 1\n"
                   "    benchmark: results/benchmarks/train/goal2d.tsv\n")
    _bench(tmp_path / "results" / "benchmarks", "train/goal2d.tsv", 300, 290, 1_000_000.0)
    record.write(default_config, tmp_path / "results", out, "time snakemake --cores 2 all", "abc123")
    # exact: one job's integer CPU seconds, its median and sum are that number
    assert (out / "rule_times.csv").read_text() == ("rule,kind,jobs,median_cpu_seconds,cpu_seconds\n"
                                                    "train,train,1,290.0,290.0\n")  # a job without wildcards
    assert "rule_times.csv" in (out / "README.md").read_text()
    # the compute table is the whole run's, written at record time, not the copy its compute job left
    assert "1 jobs, 4.8 core-minutes" in (out / "compute.md").read_text()
    assert "writes again from the whole run's benchmark files" in (out / "README.md").read_text()
    assert (tables / "compute.md").read_text() == "**compute**\n"  # exact: the run's own files are left as they were
    # a run that named its cores and kept its CPU as the kernel counted it: the record's table gives that count
    from ocpipe.bookkeeping import run_cpu

    log.write_text("Provided cores: 2\n[Thu Dec  3 00:00:00 2026]\nlocalrule train:\n    jobid: 1\n"
                   "    benchmark: results/benchmarks/train/goal2d.tsv\n[Thu Dec  3 00:05:00 2026]\nFinished job 1.\n")
    run_cpu.path_of(log, tmp_path).parent.mkdir(parents=True)
    run_cpu.path_of(log, tmp_path).write_text('{"jobs_cpu_seconds": 300.0, "snakemake_cpu_seconds": 5.0}')
    record.write(default_config, tmp_path / "results", out, "time snakemake --cores 2 all", "abc123")
    assert ("that run's jobs by the kernel's count: 5.0 core-minutes over its 5.0 min (first job's start to its "
            "log's last line), 50 % of 2 cores") in (out / "compute.md").read_text()
    (tables / "table5_7.md").unlink()
    with pytest.raises(FileNotFoundError, match="table5_7.md"):
        record.write(default_config, tmp_path / "results", out, "cmd", "abc123")


def test_the_compute_jobs_own_benchmark_is_a_table_job():
    assert compute.owner("", "compute") == ("table", "compute", "report")
    assert compute.owner("", "something_new") == ("other", "something_new", "other")


def test_record_blocks_show_the_recorded_files_and_name_a_missing_one(tmp_path):
    from ocpipe.bookkeeping import record

    (tmp_path / "table5_1.md").write_text("| a |\n|---|\n| 1 |\n")
    text = "# Results\n<!-- record: table5_1.md -->\nold table\nold line\n<!-- /record -->\nafter\n"
    assert record.fill_marked(text, tmp_path) == (
        "# Results\n<!-- record: table5_1.md -->\n| a |\n|---|\n| 1 |\n<!-- /record -->\nafter\n")
    empty = "<!-- record: table5_1.md -->\n<!-- /record -->\n"  # as a new README holds it
    assert record.fill_marked(empty, tmp_path) == (
        "<!-- record: table5_1.md -->\n| a |\n|---|\n| 1 |\n<!-- /record -->\n")
    assert record.fill_marked(record.fill_marked(text, tmp_path), tmp_path) == record.fill_marked(text, tmp_path)
    (tmp_path / "findings.md").write_text("| f |\n")
    two = ("<!-- record: table5_1.md -->\n<!-- /record -->\ntext between\n"
           "<!-- record: findings.md -->\n<!-- /record -->\n")
    assert record.fill_marked(two, tmp_path) == (  # an empty block ends at its own end marker, not the next one's
        "<!-- record: table5_1.md -->\n| a |\n|---|\n| 1 |\n<!-- /record -->\ntext between\n"
        "<!-- record: findings.md -->\n| f |\n<!-- /record -->\n")
    with pytest.raises(FileNotFoundError, match="table5_9.md"):
        record.fill_marked("<!-- record: table5_9.md -->\n\n<!-- /record -->", tmp_path)


def test_the_committed_record_is_a_whole_run_of_a_named_commit_and_readme_shows_it(default_config):
    from ocpipe.bookkeeping import record

    rec = REPO / "docs" / "results"
    record.recorded_files(default_config, rec)  # every table, the findings and the compute table, csv and md
    assert re.search(r"Commit `[0-9a-f]{40}`", (rec / "README.md").read_text())
    assert pl.read_csv(rec / "findings.csv").height == 12
    readme = (REPO / "README.md").read_text()
    assert "<!-- record: table5_1.md -->" in readme and "<!-- record: findings.md -->" in readme
    assert record.fill_marked(readme, rec) == readme  # README's Results blocks are the record's own files


# on 2 cores, features (2 threads) is ready when frames finishes at 10:01:00 and waits while train holds one core
# to 10:02:30: 1 idle core x 90 s = 1.5 core-minutes
WAITING_LOG = """Provided cores: 2
[Sun Dec  6 10:00:00 2026]
localrule frames:
    output: results/frames/a.zarr
    jobid: 1
[Sun Dec  6 10:00:00 2026]
rule train:
    output: results/runs/t/checkpoints
    jobid: 2
    threads: 1
[Sun Dec  6 10:01:00 2026]
Finished jobid: 1 (Rule: frames)
[Sun Dec  6 10:02:30 2026]
Finished jobid: 2 (Rule: train)
[Sun Dec  6 10:02:30 2026]
localrule features:
    input: results/frames/a.zarr
    output: results/features/a.zarr
    jobid: 3
    wildcards: store=a
    threads: 2
[Sun Dec  6 10:04:00 2026]
Finished jobid: 3 (Rule: features)
"""


def test_the_table_says_how_long_two_thread_jobs_waited_with_a_core_idle_or_that_no_log_tells(default_config, bench,
                                                                                               tmp_path):
    md = tmp_path / "c.md"
    compute.write(default_config, bench, tmp_path / "c.csv", md, cores=2, workdir=tmp_path)
    assert "jobs of 2+ threads waiting with a core idle: not known (no run log names its cores)" in md.read_text()
    log = tmp_path / ".snakemake" / "log" / "2026-12-06T100000.snakemake.log"
    log.parent.mkdir(parents=True)
    log.write_text(WAITING_LOG)
    compute.write(default_config, bench, tmp_path / "c.csv", md, cores=2, workdir=tmp_path)
    assert ("utilisation 65 % of 2 cores (core-minutes / (cores x wall time)); jobs of 2+ threads waited with a core "
            "idle: 1.5 core-minutes (1 of 1 such jobs: features store=a: 90 core-s in a 90 s wait; run log "
            "2026-12-06T100000.snakemake.log)") in md.read_text()


def test_the_table_gives_the_runs_cpu_by_the_kernels_count_where_the_run_kept_it(default_config, bench, tmp_path):
    from ocpipe.bookkeeping import run_cpu

    md = tmp_path / "c.md"
    log = tmp_path / ".snakemake" / "log" / "2026-12-06T100000.snakemake.log"
    log.parent.mkdir(parents=True)
    log.write_text(WAITING_LOG)
    compute.write(default_config, bench, tmp_path / "c.csv", md, cores=2, workdir=tmp_path)
    assert ("that run's CPU by the kernel's count: none kept yet (a run keeps it when it ends: ocpipe compute then "
            "gives it)") in md.read_text()
    # 6 core-minutes over the log's 4 minutes (10:00:00 to 10:04:00) on 2 cores: 75 %
    run_cpu.path_of(log, tmp_path).parent.mkdir(parents=True)
    run_cpu.path_of(log, tmp_path).write_text('{"jobs_cpu_seconds": 360.0, "snakemake_cpu_seconds": 5.0}')
    compute.write(default_config, bench, tmp_path / "c.csv", md, cores=2, workdir=tmp_path)
    assert ("that run's jobs by the kernel's count: 6.0 core-minutes over its 4.0 min (first job's start to its "
            "log's last line), 75 % of 2 cores") in md.read_text()
    run_cpu.path_of(log, tmp_path).write_text('{"jobs_cpu_seconds": 360.0}')
    with pytest.raises(ValueError, match="2026-12-06T100000.json: no snakemake_cpu_seconds"):
        compute.write(default_config, bench, tmp_path / "c.csv", md, cores=2, workdir=tmp_path)


def test_a_run_keeps_its_jobs_cpu_as_the_kernel_counts_every_process_it_waited_for(tmp_path):
    from ocpipe.bookkeeping import run_cpu

    log = tmp_path / "2026-12-07T100000.123.snakemake.log"
    assert run_cpu.record([str(log)], local=False, workdir=tmp_path) is None  # a cluster ran the jobs
    assert run_cpu.record([], local=True, workdir=tmp_path) is None  # a run without a log
    assert not (tmp_path / run_cpu.FOLDER).exists()
    run_cpu.record([str(log)], local=True, workdir=tmp_path)
    before = run_cpu.read(log, tmp_path)
    burn = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.3:\n    pass"
    subprocess.run([sys.executable, "-c", burn], check=True)  # a child of 0.3 CPU-seconds or more, waited for
    kept = run_cpu.record([str(log)], local=True, workdir=tmp_path)
    assert kept == tmp_path / run_cpu.FOLDER / "2026-12-07T100000.123.json"
    after = run_cpu.read(log, tmp_path)
    assert after["log"] == log.name
    # derived: the kernel's per-process times, kept to 2 decimals (a clock tick is 0.01 s)
    assert after["jobs_cpu_seconds"] - before["jobs_cpu_seconds"] >= 0.3 - 0.02
    with pytest.raises(ValueError, match="not a Snakemake run log"):
        run_cpu.path_of(tmp_path / "run.txt")

