import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from ocpipe.config import validate as cfgmod

REPO = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile")]
TINY = yaml.safe_load((REPO / ".test" / "config.yaml").read_text())  # the committed tiny study
TABLES = ["results/tables/table5_1.csv", "results/tables/table5_2.csv", "results/figures/fig5_1.png",
          "results/figures/fig5_2.png", "results/figures/fig5_3.png",
          "results/tables/table5_6.csv",  # an ablation table end to end: fusion, with training-seed runs
          "results/tables/findings_main.csv",
          "results/tables/levers.csv"]  # the levers target: two levers on the validation pool
# the gallery of two rows: a slot-encoder row (its sheets show slot masks) and the control, which has no camera
GALLERIES = ["results/gallery/goal2d/episodes.csv", "results/gallery/state_control/episodes.csv"]
TINY_TARGETS = ["encodings", *TABLES, *GALLERIES]  # what the tiny run builds
# fixtures that run the simulator or Snakemake end to end (minutes): a test that needs one is slow, and make
# test-fast leaves it out; the dry runs beside them take seconds and stay in the fast lane
SLOW_FIXTURES = {"tiny_run"}


def pytest_collection_modifyitems(items):
    for item in items:
        if SLOW_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


def snakemake(workdir, *args, check=True):
    proc = subprocess.run([*SNAKEMAKE, "--directory", str(workdir), *args], cwd=workdir, capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake {' '.join(args)} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """The tiny study run once for the whole session (tests/test_workflow.py, tests/test_report.py): its workdir."""
    work = tmp_path_factory.mktemp("tiny")
    (work / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    snakemake(work, "--configfile", "tiny.yaml", "--cores", "2", *TINY_TARGETS)
    return work


@pytest.fixture
def default_config():
    return cfgmod.load(REPO / "config" / "config.yaml")


@pytest.fixture
def one_policy_config(default_config):
    """The default profile with one policy per row and 3 stability runs each: the study's own shape, whose tables
    and tests read episodes alone."""
    return {**default_config, "replicates": 1, "evaluation": {**default_config["evaluation"], "stability_runs": 3}}


@pytest.fixture(autouse=True)
def torch_threads():
    """Training and encoding set torch's thread count for the process they run in; put the suite's own back after
    each test, so every test runs at the count the suite was started with (OMP_NUM_THREADS, docs/development.md)."""
    import torch

    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)
