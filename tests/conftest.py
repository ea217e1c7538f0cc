from pathlib import Path

import pytest

from ocpipe.config import validate as cfgmod

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def default_config():
    return cfgmod.load(REPO / "config" / "config.yaml")
