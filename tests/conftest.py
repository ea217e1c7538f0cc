from pathlib import Path

import pytest

from ocpipe import config as cfgmod

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def default_config():
    return cfgmod.load(REPO / "config" / "config.yaml")
