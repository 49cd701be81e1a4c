"""The code base itself: lint, format and types (run by the same test command; its layout is
``test_layout``'s)."""

import shutil
import subprocess
import sys

import pytest

from tests.support import ROOT

pytestmark = pytest.mark.unit


def _tool(name: str) -> list[str]:
    exe = shutil.which(name, path=str(ROOT / ".venv" / "bin")) or shutil.which(name)
    return [exe] if exe else [sys.executable, "-m", name]


def test_ruff_lint_and_format():
    paths = ["sim_vehicles", "swarm_sitl", "tests"]
    r = subprocess.run([*_tool("ruff"), "check", *paths], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run(
        [*_tool("ruff"), "format", "--check", *paths], cwd=ROOT, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_mypy():
    r = subprocess.run(
        [sys.executable, "-m", "mypy", "sim_vehicles", "swarm_sitl"], cwd=ROOT, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stdout + r.stderr
