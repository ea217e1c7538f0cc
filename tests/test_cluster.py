"""The tiny study through a real SLURM cluster: the one-node cluster of bin/slurm-local.sh (slurmctld, slurmd,
slurmdbd on MariaDB), Snakemake's slurm executor (plugin 2.6.1) and config/profiles/slurm-local. Every job is an
sbatch submission, polled by the plugin, and checked here against SLURM's own accounting (sacct).

Needs root (the script installs and starts the daemons). `make test-cluster` runs these tests; `make test` leaves
them out (docs/cluster.md says why). The cluster is left running afterwards: `bash bin/slurm-local.sh stop`."""

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import golden
import pytest
import yaml
from conftest import REPO
from test_workflow import TABLES  # the same targets as the local tiny run, whose tables are committed

from ocpipe.bookkeeping import progress  # the run-log reader, here on the cluster run's output

pytestmark = [pytest.mark.slow, pytest.mark.cluster, pytest.mark.timeout(5400)]

SNAKEMAKE = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile")]
PROFILE = REPO / "config" / "profiles" / "slurm-local"
SLURM_LOCAL = REPO / "bin" / "slurm-local.sh"
PACKAGES = ["slurmctld", "slurmd", "slurmdbd", "slurm-client", "mariadb-server", "munge"]  # what the script installs
TINY = yaml.safe_load((REPO / ".test" / "config.yaml").read_text())
DEFAULT = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
TARGETS = ["encodings", *TABLES]

# Rules that never go to SLURM: the workflow's localrules (evaluation.smk, levers.smk) and the target-only rule.
LOCAL_RULES = {"best", "findings", "build_comparison", "failures", "table", "figure", "figures5_1_to_5_3", "levers",
               "encodings"}
# Their benchmark folders (results/benchmarks/<folder>/ or <folder>.tsv); every other folder is named after its rule.
LOCAL_BENCHMARKS = {"best", "failures", "tables", "figures", "levers"}
# The config `compute` stage each rule takes threads and resources from (threads_of / resources_of in
# workflow/rules/*.smk; `use rule ... with:` keeps the parent's).
STAGE = {
    "demos_shard": "demos", "demos_merge": "light", "frames_shard": "frames", "frames_merge": "light",
    "frames_report": "light", "train_slots_ssl": "train_slots_ssl", "features": "features",
    "scenes_shard": "frames", "scenes": "light",
    "features_diagnostics": "light", "attention_maps": "light", "train": "train", "lever_train": "train",
    "sweep": "evaluate", "stability": "evaluate", "failure_run": "evaluate", "train_seed_run": "evaluate",
    "lever_eval": "evaluate",
}
SACCT_FIELDS = ["JobIDRaw", "JobName", "State", "AllocCPUS", "ReqMem", "TimelimitRaw", "Partition", "Account",
                "SubmitLine"]  # SubmitLine last: it is the only field that could hold a '|'
SUBMITTED = re.compile(r"Job (\d+) has been submitted with SLURM jobid (\d+) \(log: (.+?)\)\.")


def compute():
    """Config `compute` of the tiny study: config/config.yaml with .test/config.yaml over it, per stage."""
    return {stage: {**c, **TINY.get("compute", {}).get(stage, {})} for stage, c in DEFAULT["compute"].items()}


def start(workdir, *args, log="snakemake.out"):
    """Snakemake in workdir through the local cluster's profile, in the background; its output goes to workdir/log."""
    out = open(workdir / log, "w")
    proc = subprocess.Popen([*SNAKEMAKE, "--directory", str(workdir), "--profile", str(PROFILE), *args], cwd=workdir,
                            stdout=out, stderr=subprocess.STDOUT, text=True)
    out.close()
    return proc


def finish(proc, workdir, log="snakemake.out", timeout=3000):
    """Wait for Snakemake; on timeout interrupt it as a user would (Ctrl-C: the plugin scancels its jobs), and
    scancel the run's jobs if it does not stop (a process started in the background of a script ignores SIGINT)."""
    try:
        rc = proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=180)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            uuid = re.search(r"SLURM run ID: (\S+)", (workdir / log).read_text())
            if uuid:
                subprocess.run(["scancel", "--name", uuid.group(1)])
        raise AssertionError(f"snakemake did not finish within {timeout} s:\n{tail(workdir / log)}") from None
    return rc, (workdir / log).read_text()


def run(workdir, *args, log="snakemake.out", timeout=3000):
    return finish(start(workdir, *args, log=log), workdir, log=log, timeout=timeout)


def tail(path, n=60):
    return "\n".join(path.read_text().splitlines()[-n:]) if path.exists() else f"({path} missing)"


def run_id(out):
    return re.search(r"SLURM run ID: (\S+)", out).group(1)


def sacct(job_ids, settle=60):
    """sacct's record of each job (-X: the allocation, not its steps), once every job has its final state and
    its name: right after a job ends (or is cancelled), sacct can list it for a second or two as 'allocation'."""
    deadline = time.monotonic() + settle
    while True:
        out = subprocess.run(["sacct", "-X", "--parsable2", "--noheader", "-j", ",".join(job_ids),
                              "--format=" + ",".join(SACCT_FIELDS)], capture_output=True, text=True, check=True)
        rows = [dict(zip(SACCT_FIELDS, line.split("|", len(SACCT_FIELDS) - 1))) for line in out.stdout.splitlines()]
        rows = {r["JobIDRaw"]: r for r in rows if r["JobIDRaw"]}
        settled = set(rows) == set(job_ids) and all(
            r["JobName"] != "allocation" and r["State"].split()[0] not in ("PENDING", "RUNNING", "COMPLETING")
            for r in rows.values())
        if settled or time.monotonic() > deadline:
            return rows
        time.sleep(2)


def submitted_rule(row):
    """The rule and wildcards of a SLURM job, from the sbatch call sacct recorded (the job comment itself is not
    stored: slurmdbd keeps it only with AccountingStoreFlags=job_comment)."""
    m = re.search(r"--target-jobs '([\w-]+):([^']*)'", row["SubmitLine"])
    comment = re.search(r"--comment (\S+)", row["SubmitLine"]).group(1)
    return m.group(1), m.group(2), comment


def req_mem_mb(value):
    """sacct's ReqMem ('6000M'; older releases append n or c, per node or per CPU) in MB."""
    m = re.fullmatch(r"(\d+(?:\.\d+)?)([KMGT])[nc]?", value)
    return float(m.group(1)) * {"K": 1 / 1024, "M": 1, "G": 1024, "T": 1024**2}[m.group(2)]


@pytest.fixture(scope="module")
def cluster():
    """The local cluster, started (and installed) by bin/slurm-local.sh unless it runs already."""
    if os.geteuid() != 0:
        pytest.skip("the local SLURM cluster (bin/slurm-local.sh) needs root")
    if not shutil.which("sbatch") and not shutil.which("apt-get"):
        pytest.skip("no SLURM client here and no apt-get to install one (bin/slurm-local.sh is for Debian)")
    proc = subprocess.run(["bash", str(SLURM_LOCAL), "start"], capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        log = "\n".join((proc.stdout + proc.stderr).splitlines()[-30:])
        missing = [p for p in PACKAGES if "ok installed" not in subprocess.run(
            ["dpkg-query", "-W", "-f=${Status}", p], capture_output=True, text=True).stdout]
        if missing:  # e.g. no network for apt: the machine cannot run the cluster, which is not this test's finding
            pytest.skip(f"bin/slurm-local.sh start could not install {' '.join(missing)}:\n{log}")
        pytest.fail(f"bin/slurm-local.sh start failed with SLURM installed:\n{log}")
    return proc.stdout


@pytest.fixture(scope="module")
def tiny_slurm_run(cluster, tmp_path_factory):
    """The tiny study's DAG (the targets of tests/test_workflow.py's tiny run) through SLURM."""
    work = tmp_path_factory.mktemp("tiny_slurm")
    (work / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    t0 = time.monotonic()
    rc, out = run(work, *TARGETS, "--configfile", "tiny.yaml", timeout=4800)
    assert rc == 0, f"snakemake through SLURM failed (SLURM logs: {work}/.snakemake/slurm_logs):\n{out[-6000:]}"
    return {**record(work, out), "seconds": time.monotonic() - t0}


def record(work, out):
    """A finished run: its Snakemake jobs and their SLURM ids and logs, and sacct's rows for those ids."""
    jobs = {int(n): (sid, log) for n, sid, log in SUBMITTED.findall(out)}
    return {"work": work, "out": out, "uuid": run_id(out), "jobs": jobs,
            "finished": {int(m["id"]): m["rule"] for m in progress.FINISHED.finditer(out)},
            "sacct": sacct([sid for sid, _ in jobs.values()])}


def slurm_jobs_by_rule(run_):
    """Check that each job Snakemake submitted is, in sacct, a completed SLURM job of this run that ran the rule
    Snakemake named, with its log where the plugin puts it, and that Snakemake ran nothing itself but local rules;
    the jobs per rule."""
    jobs, finished, rows = run_["jobs"], run_["finished"], run_["sacct"]
    assert set(jobs) <= set(finished)
    assert {rule for n, rule in finished.items() if n not in jobs} <= LOCAL_RULES
    per_rule = Counter()
    for n, (sid, log) in jobs.items():
        row = rows[sid]
        rule, wildcards, comment = submitted_rule(row)
        assert row["State"] == "COMPLETED" and row["JobName"] == run_["uuid"], row
        assert rule == finished[n] and comment.startswith(f"rule_{rule}")
        assert row["Partition"] == "cpu" and row["Account"] == "ocpipe"
        # the plugin's per-job log: .snakemake/slurm_logs/rule_<rule>/<wildcards>/<slurm id>.log
        assert f"/.snakemake/slurm_logs/rule_{rule}/" in log and f"rule {rule}:" in Path(log).read_text()
        per_rule[rule] += 1
    # the run's own record: one benchmark file per job that ran, the local rules' aside
    bench = run_["work"] / "results" / "benchmarks"
    ran = Counter(p.relative_to(bench).parts[0].removesuffix(".tsv") for p in bench.rglob("*.tsv"))
    assert per_rule == Counter({k: v for k, v in ran.items() if k not in LOCAL_BENCHMARKS})
    return per_rule


def allocations(run_, declared):
    """Check that SLURM allocated each job the threads (AllocCPUS), mem_mb (ReqMem) and runtime (TimelimitRaw)
    of its rule's stage in `declared` (config `compute`); the (rule, (cpus, MB)) pairs seen."""
    seen = set()
    for sid, _ in run_["jobs"].values():
        row = run_["sacct"][sid]
        rule = submitted_rule(row)[0]
        assert rule in STAGE, f"rule {rule} ran on SLURM but this test does not know its compute stage"
        c = declared[STAGE[rule]]
        got = (int(row["AllocCPUS"]), req_mem_mb(row["ReqMem"]), int(row["TimelimitRaw"]))
        assert got == (c["threads"], c["mem_mb"], c["runtime"]), (rule, row)
        seen.add((rule, got[:2]))
    return seen


def test_every_job_ran_as_a_slurm_job(tiny_slurm_run):
    per_rule = slurm_jobs_by_rule(tiny_slurm_run)
    assert sum(per_rule.values()) > 40  # the tiny DAG: ~55 jobs outside the local rules
    print(f"{sum(per_rule.values())} SLURM jobs in {tiny_slurm_run['seconds'] / 60:.1f} min: {dict(per_rule)}")


def test_slurm_allocates_what_each_rule_declares(tiny_slurm_run):
    declared = compute()
    seen = allocations(tiny_slurm_run, declared)
    # at least the encoder's 2 threads / 6000 MB and a light job's 1 / 2000 MB, as config `compute` sets them
    t, light = declared["train_slots_ssl"], declared["light"]
    assert ("train_slots_ssl", (t["threads"], t["mem_mb"])) in seen
    assert ("demos_merge", (light["threads"], light["mem_mb"])) in seen
    assert (t["threads"], t["mem_mb"]) != (light["threads"], light["mem_mb"])


def test_tables_are_the_local_runs(tiny_slurm_run):
    """The committed tables of the local tiny run in everything no float kernel decides (tests/golden.py): the same
    rows, columns, counts and episode seeds through SLURM."""
    differ = golden.differences(tiny_slurm_run["work"] / "results")
    assert not differ, "through SLURM differs from tests/expected/tiny:\n" + "\n".join(differ)


def test_a_cancelled_job_fails_the_run_and_a_rerun_completes(cluster, tmp_path):
    """scancel on a job running its rule: Snakemake reports the rule failed and exits non-zero; a rerun completes.
    The StackCube demos (a ~20 s motion-planning job, then the merge) keep it cheap."""
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    args = ["results/demos/StackCube-v1.h5", "--configfile", "tiny.yaml"]
    proc = start(tmp_path, *args, log="first.out")
    deadline, m = time.monotonic() + 600, None
    while not m and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(1)
        m = SUBMITTED.search((tmp_path / "first.out").read_text())
    assert m, f"no SLURM submission seen:\n{tail(tmp_path / 'first.out')}"
    sid = m.group(2)
    steps = []
    while f"{sid}.0" not in steps and time.monotonic() < deadline:  # step 0: the srun that runs the rule's script
        time.sleep(0.5)
        steps = subprocess.run(["squeue", "-h", "-s", "-j", sid, "-o", "%i"], capture_output=True,
                               text=True).stdout.split()
    assert f"{sid}.0" in steps, f"SLURM job {sid} never started its rule (steps: {steps})"
    time.sleep(2)  # into the rule's work (motion planning takes ~20 s here)
    subprocess.run(["scancel", sid], check=True)
    rc, out = finish(proc, tmp_path, log="first.out", timeout=600)
    assert rc != 0
    assert "Error in rule demos_shard:" in out and f"SLURM-job '{sid}' failed, SLURM status is: 'CANCELLED'" in out
    assert sacct([sid])[sid]["State"].startswith("CANCELLED")
    log = next((tmp_path / ".snakemake" / "slurm_logs" / "rule_demos_shard").rglob(f"{sid}.log"))
    assert f"JOB {sid} ON" in log.read_text() and "CANCELLED" in log.read_text()  # slurmstepd's line
    assert not (tmp_path / "results" / "demos" / "StackCube-v1.h5").exists()

    rc, out = run(tmp_path, *args, "--rerun-incomplete", log="rerun.out", timeout=900)
    assert rc == 0, out[-4000:]
    again = {m[1] for m in SUBMITTED.findall(out)}
    assert len(again) == 2 and all(r["State"] == "COMPLETED" for r in sacct(sorted(again)).values())
    assert (tmp_path / "results" / "demos" / "StackCube-v1.h5").stat().st_size > 0


def test_a_gpu_stage_asks_sbatch_for_a_gpu(cluster, tmp_path):
    """compute: {train: {gpu: 1}} reaches sbatch as --gpus=1 (the plugin's form for resource `gpu`). This cluster
    has no GPU (no GresTypes), so sbatch refuses the job and the error shows the call. Nothing runs: the train
    job's inputs are empty placeholders, and --allowed-rules keeps Snakemake from building them."""
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    (tmp_path / "gpu.yaml").write_text(yaml.safe_dump({"compute": {"train": {"gpu": 1}}}))
    args = ["results/runs/goal2d/train_log.parquet", "--allowed-rules", "train", "--configfile", "tiny.yaml",
            "gpu.yaml"]
    rc, out = run(tmp_path, "-n", *args, log="dry.out", timeout=300)
    assert rc != 0 and "Missing input files for rule train" in out
    inputs = re.findall(r"^\s{6,}(results/\S+)$", out.split("affected files:", 1)[1], re.M)
    assert inputs
    for path in inputs:
        (tmp_path / path).mkdir(parents=True)
    rc, out = run(tmp_path, *args, log="submit.out", timeout=300)
    assert rc != 0 and "Error in rule train:" in out
    call = next(line for line in out.splitlines() if line.strip().startswith("sbatch --"))
    assert " --gpus=1" in call and " -p cpu" in call and "--comment rule_train_wildcards_goal2d" in call
    train = compute()["train"]
    assert f"--cpus-per-task={train['threads']}" in call and f"--mem {train['mem_mb']}" in call
    assert "Invalid generic resource (gres) specification" in out  # sbatch's refusal: the cluster has no GPU
    queued = subprocess.run(["squeue", "-h", "--name", run_id(out)], capture_output=True, text=True).stdout
    assert queued.strip() == ""
