"""The code base itself: layering, lint, format and types (run by the same test command)."""

import ast
import shutil
import subprocess
import sys

import pytest

from tests.conftest import ROOT

pytestmark = pytest.mark.unit


def _imports(package: str) -> set[tuple[str, str]]:
    found = set()
    for path in (ROOT / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found |= {(path.name, a.name) for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module:
                found.add((path.name, node.module))
    return found


def test_sim_vehicles_does_not_depend_on_the_swarm():
    bad = {(f, m) for f, m in _imports("sim_vehicles") if m.split(".")[0] == "swarm_sitl"}
    assert not bad, f"sim_vehicles must be usable alone: {sorted(bad)}"


def test_pure_laws_do_no_io():
    pure = [
        "quaternion.py",
        "rigid_body.py",
        "torque_law.py",
        "estimator.py",
        "position_loop.py",
        "command_attitude.py",
        "follower_law.py",
        "graph.py",
        "trajectories.py",
    ]
    io_modules = {"socket", "zenoh", "pymavlink", "subprocess", "time", "logging", "os", "threading"}
    for pkg in ("sim_vehicles", "swarm_sitl"):
        for f, m in _imports(pkg):
            if f in pure:
                assert m.split(".")[0] not in io_modules, f"{pkg}/{f} imports {m}"


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
