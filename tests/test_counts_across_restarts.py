"""Counts that add up across a process's incarnations: what a killed node published survives it
(``sim_vehicles.runtime.counter_file``), so every edge's ``sent`` covers what was received."""

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from sim_vehicles.runtime.counter_file import CounterFile, read_counter, read_named_counts
from sim_vehicles.runtime.row_log import read_rows
from tests.support import CONFIGS

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep


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


@pytest.mark.unit
def test_named_counts_outlive_a_process_killed_with_sigkill(tmp_path):
    path = tmp_path / "c.counts"
    code = (
        "import os, signal\n"
        "from pathlib import Path\n"
        "from sim_vehicles.runtime.counter_file import NamedCounts\n"
        f"c = NamedCounts(Path({str(path)!r}), ['in 1 received', 'in 1 lost', 'x'])\n"
        "v = c.view(['in 1 received', 'in 1 lost'])\n"
        "for _ in range(321): v[0] += 1\n"
        "v[1] += 7\n"
        "c.values[2] = -5\n"
        "os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60)
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert read_named_counts(path) == {"in 1 received": 321, "in 1 lost": 7, "x": -5}
    path.write_bytes(path.read_bytes()[:-3])  # cut: not a counts file any more
    assert read_named_counts(path) is None and read_named_counts(tmp_path / "none") is None


@pytest.mark.system
def test_a_killed_receivers_counts_add_up_with_its_restarted_incarnation(swarm):
    """Controller 4 (in-edges 1 -> 4 and 2 -> 4, and its MAVLink link, both under the plan) is
    killed at 1 s and restarted 0.5 s later, in lockstep. Its first incarnation counted the steps it
    waited for before the kill (0..99), the second those from its resume tick: the summary has
    both, exactly, and sent >= received on every edge."""
    dur = 3.0
    r = swarm(
        CONFIGS / "paper.yaml",
        duration_s=dur,
        faults=[
            {"controller": 4, "kill": True, "from_s": 1.0, "restart_after_s": 0.5},
            {"edge": [1, 4], "loss": 0.3},
            {"mavlink": 4, "loss": 0.2},
        ],
        seed=2,
    )
    assert r.ok, r.failure
    n = round(dur / 0.01)
    _, rows = read_rows(r.run_dir / "procs" / "controller_4.1.rows")
    resumed = int(rows[0, 0])
    assert resumed == 150
    for src in (1, 2):
        link = r.links[f"{src}->4"]
        assert link["received"] == 100 + (n - resumed), (src, link)  # steps 0..99, then 150..n-1
        assert link["received"] == link["delivered"] + link["lost"]
        assert link["sent"] >= link["received"]
    killed = read_named_counts(r.run_dir / "procs" / "controller_4.counts")
    assert killed is not None and killed["in 1 received"] == 100
    assert killed["mavlink up received"] > 0 and killed["mavlink down received"] > 0
    for way in ("up", "down"):
        total = r.links[f"mavlink 4 {way}"]["received"]
        again = json.loads((r.run_dir / "procs" / "controller_4.1.stats.json").read_text())["mavlink"][way]
        assert total == again["received"] + killed[f"mavlink {way} received"], way


@pytest.mark.unit
def test_a_counts_file_with_names_this_version_does_not_write_is_read_for_what_it_has(tmp_path):
    """merge never fails on a killed incarnation's counts: names it does not know are left out."""
    from sim_vehicles.runtime.counter_file import NamedCounts
    from swarm_sitl.faults.counts import EdgeStats
    from swarm_sitl.rundir.merge import _killed_stats

    foreign = [f"x 2 {f}" for f in EdgeStats.FIELDS]  # a whole edge's counts under a head it does not know
    mavlink = [f"mavlink up {f}" for f in EdgeStats.FIELDS]
    names = [
        "odd",
        *(f"in 2 {f}" for f in EdgeStats.FIELDS),
        "x y received",
        "in 3 received",
        *foreign,
        *mavlink,
    ]
    c = NamedCounts(tmp_path / "c.counts", names)
    c.values[1] = 5  # in 2 received
    c.values[3] = 2  # in 2 lost
    c.values[names.index(foreign[0])] = 9
    c.values[names.index("mavlink up received")] = 4
    got = _killed_stats(tmp_path / "c.counts")
    zeros = dict.fromkeys(sorted(EdgeStats.FIELDS), 0)
    assert got == {
        "in_edges": {"2": {**zeros, "received": 5, "lost": 2}},
        "mavlink": {"up": {**zeros, "received": 4}},
    }
    assert _killed_stats(tmp_path / "none.counts") == {"in_edges": {}, "mavlink": {}}
