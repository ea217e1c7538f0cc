"""End-to-end faults on a tiny config: the whole Snakemake run killed with SIGKILL (its process group, jobs
included) while a frames shard, the features job, a training job and an evaluation job run, each time followed by
a rerun; the recovered results must equal an uninterrupted run's. And a second Snakemake run on a folder that
another run holds. docs/failure-modes.md describes what these tests observe."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import h5py
import numpy as np
import polars as pl
import pytest
import yaml
import zarr
from conftest import REPO
from polars.testing import assert_frame_equal

from ocpipe.config.validate import deep_merge

pytestmark = pytest.mark.slow  # Snakemake end to end: minutes (make test-fast leaves them out)

SNAKEMAKE = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile")]
# one policy's chain (train, sweep, best, stability) with a single training job; a table would need the several
# experiments its findings compare (config refuses a Table 5.1 without them)
TARGET = "results/runs/goal2d/stability/run_0.episodes.parquet"
EPOCHS, SAVE_EVERY = 16, 8
# the committed tiny study (.test/config.yaml), with what the kill tests need on top
TINY = deep_merge(yaml.safe_load((REPO / ".test" / "config.yaml").read_text()), {
    "replicates": 1,  # one policy per experiment: the kill tests plan exact job sets around one training job
    "tasks": ["PickCube-v1"],
    # grid 48 (the default) rather than 16: encoding then takes seconds, not 0.2 s, so the kill can land while the
    # features job writes its store
    "encoders": {"slots_ssl": {"train_stores": ["PickCube-v1_dual_64"], "holdout_episodes": 1, "steps": 10,
                               "grid": 48, "batch_size": 8, "warmup_steps": 2, "slot_dim": 32, "feature_dim": 32}},
    # batch 2 and 16 epochs: an epoch takes a few tenths of a second, so there are seconds between the first kept
    # checkpoint (epoch 8) and the end of training for the kill to land in
    "policy": {"resolution": 64, "window": 3, "horizon": 4, "width": 32, "layers": 1, "heads": 4, "epochs": EPOCHS,
               "save_every": SAVE_EVERY, "batch_size": 2, "val_episodes": 1,
               # no scenes job: the kill tests plan exact job sets, and the scenes job would race the features job
               "object_readout": False, "readout_scenes": False, "visual_head": "tokens"},
    "evaluation": {"episode_cap": {"PickCube-v1": 12}, "execute_actions": 2, "sweep_episodes": 1, "stability_runs": 1,
                   "stability_episodes": 1},
    # one thread per job, so no result depends on how a reduction was split across threads: two runs of this
    # config are bit-identical
    "compute": {stage: {"threads": 1} for stage in ("demos", "frames", "train_slots_ssl", "features", "train",
                                                    "evaluate", "light")},
})
LOCKED = "Error: Directory cannot be locked. Please make sure that no other Snakemake process is trying to create"
UNLOCKED = "Unlocked working directory."
INCOMPLETE = "seem to be incomplete"
# wall-clock measurements stored next to results: they differ between any two runs, so they are left out of the
# comparison (training history 'seconds', the encoder's 'train_seconds', a frames shard's 'render_seconds', ...)
TIMING_KEYS = {"seconds", "train_seconds", "render_seconds", "encode_seconds", "frames_per_s", "frames_per_second"}
WAIT_S = 300  # per stage: a loaded 2-core machine runs the tiny chain in minutes, not tens of minutes


def workdir(path: Path, config: dict = TINY) -> Path:
    path.mkdir(parents=True)
    (path / "tiny.yaml").write_text(yaml.safe_dump(config))
    return path


def command(work: Path, *args) -> list[str]:
    return [*SNAKEMAKE, "--directory", str(work), "--configfile", "tiny.yaml", "--cores", "2", *args]


def snakemake(work: Path, *args) -> tuple[int, str]:
    proc = subprocess.run(command(work, *args), cwd=work, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True)
    return proc.returncode, proc.stdout


def _group_alive(pgid: int) -> bool:
    """Whether a process of the group still runs (zombies waiting for init to reap them do not count)."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            state, _ppid, pgrp = stat.read_text().rsplit(")", 1)[1].split()[:3]
        except (OSError, IndexError):
            continue
        if int(pgrp) == pgid and state != "Z":
            return True
    return False


class Run:
    """A Snakemake run in the background, in a session of its own: one killpg takes its jobs down with it, as a
    lost node or the OOM killer would."""

    def __init__(self, work: Path, out: Path, *args):
        self.out = out
        with out.open("w") as fh:
            self.proc = subprocess.Popen(command(work, *args), cwd=work, stdout=fh, stderr=subprocess.STDOUT,
                                         start_new_session=True)

    def text(self) -> str:
        return self.out.read_text()

    def kill(self) -> None:
        pgid = self.proc.pid
        try:
            os.killpg(pgid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait()
        # SIGKILL is delivered asynchronously: a job still running would race the rerun for the same files
        deadline = time.monotonic() + 30
        while _group_alive(pgid):
            assert time.monotonic() < deadline, f"processes of the killed run {pgid} still run after 30 s"
            time.sleep(0.05)

    def finish(self, timeout: float = 600) -> str:
        rc = self.proc.wait(timeout)
        assert rc == 0, f"snakemake failed (exit {rc}):\n{self.text()[-4000:]}"
        return self.text()


def wait_for(run: Run, what: str, found, timeout: float = WAIT_S):
    """Poll ``found()`` until it returns something true; fail naming ``what`` if the run ends first or it takes
    longer than ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        hit = found()
        if hit:
            return hit
        if run.proc.poll() is not None:
            raise AssertionError(f"snakemake ended (exit {run.proc.returncode}) before {what}:\n{run.text()[-4000:]}")
        if time.monotonic() > deadline:
            raise AssertionError(f"no sign of {what} after {timeout} s:\n{run.text()[-4000:]}")
        time.sleep(0.02)


def jobs_planned(dry_run: str) -> set[str]:
    return set(re.findall(r"^(?:local)?rule (\w+):", dry_run, flags=re.M))


def recover(work: Path, logs: Path, name: str, redone: set[str], kept: set[str]) -> Run:
    """After a hard kill: the same command stops at the lock the killed run left, --unlock removes it, a dry run
    without --rerun-incomplete plans only ``redone`` work (never ``kept``), and the rerun starts in the
    background."""
    rc, out = snakemake(work, TARGET)
    assert rc != 0 and LOCKED in out and str(work) in out, f"after killing {name}, a rerun ignored the lock:\n{out}"
    rc, out = snakemake(work, "--unlock")
    assert rc == 0 and UNLOCKED in out, out
    rc, out = snakemake(work, "-n", TARGET)
    # the killed jobs' outputs are written to temporaries and renamed at the end, so none exists at its final path
    # and Snakemake has no existing-but-incomplete file to complain about: --rerun-incomplete is not needed here
    assert rc == 0 and INCOMPLETE not in out, f"after killing {name}:\n{out}"
    planned = jobs_planned(out)
    assert redone <= planned and not planned & kept, f"after killing {name}, the rerun plans {sorted(planned)}"
    return Run(work, logs / f"rerun_after_{name}.out", "--rerun-incomplete", TARGET)


def test_killed_runs_rerun_to_the_results_of_an_uninterrupted_run(tmp_path):
    import torch

    base, work, logs = workdir(tmp_path / "baseline"), workdir(tmp_path / "killed"), tmp_path / "out"
    logs.mkdir()
    res = work / "results"
    shards = res / "frames" / "shards" / "PickCube-v1_dual_64"
    features = res / "features" / "PickCube-v1_dual_64_slots_ssl.zarr"
    run_dir = res / "runs" / "goal2d"
    runs: list[Run] = []
    try:
        # the baseline runs alongside the killed chain: both are mostly one job wide, so together they keep the
        # two cores busy
        baseline = Run(base, logs / "baseline.out", TARGET)
        runs.append(baseline)

        # (a) a frames shard, once its store is being written
        runs.append(run := Run(work, logs / "first.out", TARGET))
        wait_for(run, "a frames_shard job writing its store", lambda: list(shards.glob(".tmp-*-shard*.zarr")))
        run.kill()
        assert not list(shards.glob("shard*.zarr")) and not (res / "frames" / "PickCube-v1_dual_64.zarr").exists()
        runs.append(run := recover(work, logs, "frames_shard", {"frames_shard", "frames_merge"},
                                   {"demos_shard", "demos_merge"}))

        # (b) the features job, once its store is being written
        wait_for(run, "the features job writing its store",
                 lambda: list(features.parent.glob(f".tmp-*-{features.name}")))
        run.kill()
        assert not features.exists(), "the features job ended before the kill: make its encoding slower"
        runs.append(run := recover(work, logs, "features", {"features", "train"},
                                   {"frames_shard", "frames_merge", "train_slots_ssl"}))

        # (c) training, once the resume state of the first kept checkpoint's epoch is saved: one kept checkpoint
        # made before the kill, one after
        state, kept = run_dir / ".train" / "state.pt", run_dir / ".train" / f"epoch_{SAVE_EVERY:04d}.pt"
        # state.pt is renamed into place after the epoch's kept checkpoint: newer than it, it is that epoch's
        wait_for(run, f"training past epoch {SAVE_EVERY}",
                 lambda: kept.is_file() and state.is_file() and state.stat().st_mtime_ns >= kept.stat().st_mtime_ns)
        run.kill()
        assert not (run_dir / "checkpoints").exists() and not (run_dir / "train_log.parquet").exists(), (
            "training ended before the kill: make its epochs longer")
        done = torch.load(state, weights_only=False)["epoch"]
        assert SAVE_EVERY <= done < EPOCHS
        runs.append(run := recover(work, logs, "train", {"train", "sweep"}, {"features", "train_slots_ssl"}))

        # (d) an evaluation job; by then the rerun has finished training, resumed rather than started over
        wait_for(run, "an evaluation (sweep) job", lambda: list((res / "logs" / "sweep").glob("*.log")))
        train_log = (res / "logs" / "train" / "goal2d.log").read_text()
        assert f"resuming goal2d after epoch {done}\n" in train_log, train_log[-3000:]
        trained = [int(e) for e in re.findall(r"^epoch (\d+): ", train_log, flags=re.M)]
        assert trained == list(range(done + 1, EPOCHS + 1)), train_log[-3000:]
        run.kill()
        assert not list(run_dir.glob("sweep*.parquet")), "the sweep job ended before the kill"
        runs.append(run := recover(work, logs, "sweep", {"sweep", "best", "stability"}, {"train"}))
        run.finish()
        baseline.finish()
    finally:
        for r in runs:
            if r.proc.poll() is None:
                r.kill()

    ours, theirs = artifacts(work / "results"), artifacts(base / "results")
    leftovers = sorted(p for p in ours if Path(p).name.startswith(".tmp-"))
    ours = {p: f for p, f in ours.items() if p not in leftovers}
    assert ours.keys() == theirs.keys()
    assert not [p for p in theirs if Path(p).name.startswith(".tmp-")]
    # what a SIGKILL may leave: temporaries of the killed frames shards (one or both, depending on how far each
    # got) and features job, beside the final paths, never at them; nothing reads them
    assert {re.sub(r"\.tmp-\d+-", ".tmp-*-", p) for p in leftovers} <= {
        "frames/shards/PickCube-v1_dual_64/.tmp-*-shard0.zarr", "frames/shards/PickCube-v1_dual_64/.tmp-*-shard1.zarr",
        "features/.tmp-*-PickCube-v1_dual_64_slots_ssl.zarr"}, leftovers
    # text files byte for byte, stores array by array, parquet frames by content (differences())
    diffs = [d for p in theirs for d in differences(ours[p], theirs[p], p)]
    assert not diffs, "\n".join(diffs)


def test_a_second_run_on_a_held_folder_stops_at_the_lock(tmp_path):
    work, target = workdir(tmp_path / "held"), "results/demos/shards/PickCube-v1/shard0.json"
    first = Run(work, tmp_path / "first.out", target)
    try:
        log = work / "results" / "logs" / "demos_shard" / "PickCube-v1_shard0.log"
        wait_for(first, "the demos_shard job", log.is_file)
        # frozen, the first run keeps holding the folder, and its job cannot rename outputs into place meanwhile
        # (Snakemake would report existing outputs of a running job as incomplete before it looks at the lock)
        os.killpg(first.proc.pid, signal.SIGSTOP)
        rc, out = snakemake(work, target)
    finally:
        first.kill()
    assert rc != 0 and LOCKED in out and str(work) in out and "--unlock argument" in out, out
    assert not (work / target).exists()
    # a killed run cannot release its lock: the same command still stops
    rc, out = snakemake(work, target)
    assert rc != 0 and LOCKED in out, out
    rc, out = snakemake(work, "--unlock")
    assert rc == 0 and UNLOCKED in out, out
    rc, out = snakemake(work, target)
    assert rc == 0 and "1 of 1 steps (100%) done" in out and (work / target).is_file(), out


def artifacts(results: Path) -> dict[str, Path]:
    """Every file or zarr store under results/ by its relative path, a temporary (.tmp-*) as one entry. Logs and
    benchmarks are left out: they record progress and timings, not results."""
    out = {}
    for p in sorted(results.rglob("*")):
        rel = p.relative_to(results)
        if rel.parts[0] in ("logs", "benchmarks"):
            continue
        inner = rel.parts[:-1]
        if any(part.endswith(".zarr") or part.startswith(".tmp-") for part in inner):
            continue  # inside a store or a temporary: it is compared (or reported) as a whole
        if p.is_file() or p.suffix == ".zarr" or p.name.startswith(".tmp-"):
            out[str(rel)] = p
    return out


def differences(a: Path, b: Path, where: str) -> list[str]:
    if a.name == ".snakemake_timestamp":  # Snakemake's marker of a directory output: its mtime is all it holds
        return []
    if a.suffix == ".zarr":
        return _zarr_differences(a, b, where)
    if a.suffix == ".parquet":
        x, y = (pl.read_parquet(p).drop(TIMING_KEYS, strict=False) for p in (a, b))
        try:
            # one-cpu: both runs trained and evaluated on this machine; float kernels decide the last bits elsewhere
            assert_frame_equal(x, y, check_exact=True)
        except AssertionError as err:
            return [f"{where}: {err}"]
        return []
    if a.suffix == ".json":
        return _tree_differences(json.loads(a.read_text()), json.loads(b.read_text()), where)
    if a.suffix == ".pt":
        import torch

        return _tree_differences(torch.load(a, weights_only=False), torch.load(b, weights_only=False), where)
    if a.suffix == ".h5":
        return _h5_differences(a, b, where)
    # one-cpu: two builds on this machine, byte for byte (another CPU's float kernels may round the numbers apart)
    return [] if a.read_bytes() == b.read_bytes() else [f"{where}: the bytes differ"]


def _arrays_differ(x: np.ndarray, y: np.ndarray) -> bool:
    # one-cpu: arrays of the killed-and-rerun build against the uninterrupted one, both computed on this machine
    return x.shape != y.shape or x.dtype != y.dtype or not np.array_equal(x, y, equal_nan=x.dtype.kind in "fc")


def _tree_differences(a, b, where: str) -> list[str]:
    import torch

    if isinstance(a, dict) and isinstance(b, dict):
        keys = set(a) - TIMING_KEYS, set(b) - TIMING_KEYS
        if keys[0] != keys[1]:
            return [f"{where}: keys {sorted(map(str, keys[0] ^ keys[1]))} in one only"]
        return [d for k in sorted(keys[0], key=str) for d in _tree_differences(a[k], b[k], f"{where}/{k}")]
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return [f"{where}: length {len(a)} vs {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _tree_differences(x, y, f"{where}[{i}]")]
    if isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor):
        a, b = a.detach().cpu().numpy(), b.detach().cpu().numpy()
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return [f"{where}: arrays differ"] if _arrays_differ(a, b) else []
    if isinstance(a, float) and isinstance(b, float) and a != a and b != b:
        return []
    # one-cpu: the two runs' scalars (losses, rates from JSON and checkpoints) compared exactly, as their arrays are
    return [] if type(a) is type(b) and a == b else [f"{where}: {a!r} vs {b!r}"]


def _zarr_differences(a: Path, b: Path, where: str) -> list[str]:
    ga, gb = zarr.open_group(str(a), mode="r"), zarr.open_group(str(b), mode="r")
    diffs = _tree_differences(ga.attrs.asdict(), gb.attrs.asdict(), f"{where} attrs")
    with warnings.catch_warnings():  # the .snakemake_timestamp Snakemake puts in directory outputs is no zarr node
        warnings.simplefilter("ignore", UserWarning)
        ma, mb = dict(ga.members(max_depth=None)), dict(gb.members(max_depth=None))
    if ma.keys() != mb.keys():
        return [*diffs, f"{where}: members {sorted(ma.keys() ^ mb.keys())} in one only"]
    for name in sorted(ma):
        x, y = ma[name], mb[name]
        diffs += _tree_differences(x.attrs.asdict(), y.attrs.asdict(), f"{where}/{name} attrs")
        if isinstance(x, zarr.Array) and _arrays_differ(x[...], y[...]):
            diffs.append(f"{where}/{name}: arrays differ")
    return diffs


def _h5_differences(a: Path, b: Path, where: str) -> list[str]:
    def tree(f: h5py.File) -> dict:
        out = {"/": dict(f.attrs)}
        f.visititems(lambda name, obj: out.__setitem__(
            name, {"attrs": dict(obj.attrs), **({"data": obj[()]} if isinstance(obj, h5py.Dataset) else {})}))
        return out

    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        return _tree_differences(tree(fa), tree(fb), where)
