"""A pytest plugin, installed with the package: the ``swarm`` fixture for fault-injection tests.

    def test_cut_edge(swarm):
        r = swarm("configs/paper.yaml", duration_s=45,
                  faults=[{"edge": [0, 1], "drop": True, "from_s": 20, "until_s": 30}])
        assert r.max_formation_error_m(after_s=45 - 5) < 0.05

``swarm(config, duration_s=None, **kwargs)`` runs ``swarm_sitl.Swarm(config, **kwargs)`` in the
test's temporary directory and returns its ``SwarmResult``; the run directory stays there for a
failing test to be looked at (``result.run_dir``).
"""

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from swarm_sitl.api import Swarm, SwarmResult


@pytest.fixture
def swarm(tmp_path: Path) -> Callable[..., SwarmResult]:
    count = [0]

    def run(config: Any, duration_s: float | None = None, **kwargs: Any) -> SwarmResult:
        count[0] += 1
        with Swarm(config, out=tmp_path / f"swarm-{count[0]}", **kwargs) as s:
            return s.run(duration_s)

    return run
