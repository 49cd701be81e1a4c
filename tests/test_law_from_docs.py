"""A law written from ``docs/laws.md`` alone, outside the repository: the page's files, in a
temporary directory, through the page's commands (new --law, check, sim, and its fault test
through the ``swarm`` fixture, run by pytest there)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support import ROOT, cli, page_files

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = [pytest.mark.system, pytest.mark.lockstep]
GUIDE = ROOT / "docs" / "laws.md"
COMMANDS = [
    "swarm-sitl new --followers 4 --graph layered --duration 12 --law my_law.py:RelayPD -o my_swarm.yaml",
    "swarm-sitl check my_swarm.yaml",
    "swarm-sitl sim my_swarm.yaml --out runs/mine-sim",
    "python -m pytest test_my_law.py",
]


def _sh(cmd: str, cwd: Path) -> subprocess.CompletedProcess:
    argv = cmd.split()
    if argv[0] == "swarm-sitl":
        return cli(*argv[1:], cwd=cwd, timeout=300)
    return subprocess.run([sys.executable, *argv[1:]], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_the_guides_law_loads_by_its_entry_flies_and_passes_its_fault_test(tmp_path):
    text = GUIDE.read_text()
    files = page_files(text)
    assert set(files) == {"my_law.py", "test_my_law.py"}
    for name, code in files.items():
        (tmp_path / name).write_text(code)
    for cmd in COMMANDS:
        assert cmd in text  # the page says exactly these
        r = _sh(cmd, tmp_path)
        assert r.returncode == 0, f"{cmd}: {r.stdout}{r.stderr}"
        if cmd.startswith("swarm-sitl check"):
            assert (
                "first tick ok" in r.stdout
                and "Theorem 1's gain conditions belong to the paper's law" in r.stdout
            )
    run = tmp_path / "runs" / "mine-sim"
    for i in range(1, 5):
        f = np.load(run / f"follower_{i}.npz")
        err = np.linalg.norm(f["pos_err_m"], axis=1)
        assert err[f["t_s"] >= 9].max() < 0.05  # in formation
        assert f["p_hat"].shape == (len(f["t_s"]), 3) and f["heard"].shape == (len(f["t_s"]),)
        assert f["heard"][1:].min() >= 1  # from tick 1 on it hears its in-neighbours
