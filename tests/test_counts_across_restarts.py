"""Counts that add up across a process's incarnations: what a killed node published survives it
(``sim_vehicles.runtime.counter_file``), so every edge's ``sent`` covers what was received."""

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from sim_vehicles.runtime.counter_file import CounterFile, read_counter
from sim_vehicles.runtime.row_log import read_rows
from tests.conftest import CONFIGS


@pytest.mark.unit
def test_a_count_outlives_a_process_killed_with_sigkill(tmp_path):
    path = tmp_path / "n.published"
    code = (
        "import os, signal, sys\n"
        "from pathlib import Path\n"
        "from sim_vehicles.runtime.counter_file import CounterFile\n"
        f"c = CounterFile(Path({str(path)!r}))\n"
        "for _ in range(1234): c.add()\n"
        "os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60)
    assert r.returncode == -signal.SIGKILL
    assert read_counter(path) == 1234
    c = CounterFile(path)  # a new counter starts from 0
    assert read_counter(path) == 0
    c.add(5)
    assert read_counter(path) == 5
    assert read_counter(tmp_path / "none") is None
    os.remove(path)


@pytest.mark.system
def test_sent_adds_up_across_a_killed_and_restarted_sender(swarm):
    """Controller 1 (edge 1 -> 4) is killed at 1 s and restarted 0.5 s later, in lockstep: 1 -> 4's
    ``sent`` is what both incarnations published (ticks 0..99, then from where it resumed to the
    end), and at least what 4 received."""
    r = swarm(
        CONFIGS / "paper.yaml",
        duration_s=3.0,
        faults=[{"controller": 1, "kill": True, "from_s": 1.0, "restart_after_s": 0.5}],
    )
    assert r.ok, r.failure
    link = r.links["1->4"]
    _, rows = read_rows(r.run_dir / "procs" / "controller_1.1.rows")
    resumed = int(rows[0, 0])  # the restarted incarnation's first tick
    n = round(3.0 / 0.01)
    assert link["sent"] == 100 + (n + 1 - resumed)  # tick 100 killed it before it published
    assert link["sent"] >= link["received"] > 0
    assert np.isfinite(r.followers[1].formation_error_m[-1])
