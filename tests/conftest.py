from pathlib import Path

import pytest

from ocpipe.config import validate as cfgmod

REPO = Path(__file__).resolve().parents[1]


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
