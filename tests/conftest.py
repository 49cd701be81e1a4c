from pathlib import Path

import pytest
from hypothesis import settings

# kernels are compiled (or loaded from cache) on first call: no per-example deadline
settings.register_profile("swarm", deadline=None, max_examples=100)
settings.load_profile("swarm")

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"


@pytest.fixture(scope="session")
def paper_cfg():
    from swarm_sitl.config.load import load_config

    return load_config(CONFIGS / "paper.yaml")


@pytest.fixture(scope="session")
def ring_cfg():
    from swarm_sitl.config.load import load_config

    return load_config(CONFIGS / "ring.yaml")
