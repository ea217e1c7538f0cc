from pathlib import Path

import pytest

from ocpipe.config import validate as cfgmod

REPO = Path(__file__).resolve().parents[1]
# fixtures that run the simulator or Snakemake end to end (minutes): a test that needs one is slow, and make
# test-fast leaves it out; the dry runs beside them take seconds and stay in the fast lane
SLOW_FIXTURES = {"tiny_run"}


def pytest_collection_modifyitems(items):
    for item in items:
        if SLOW_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


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
