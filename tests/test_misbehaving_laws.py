"""A user's law that misbehaves in follower 2 from t = 0.5 s (``tests/misbehaving_laws.py``):
``sys.exit(0)``, ``os._exit(3)``, an endless loop, 50 ms per tick, memory without bound, 10 kB
printed per tick. In ``sim`` and in a lockstep run (``test_misbehaving_laws_realtime.py``: in real
time), each ends with the one line that names the law, the follower, the tick and what it did
(exit code 1), or flies to the end (the slow law, the chatty one: exit 0); the run directory is
readable; no process is left; the wall time is bounded by the run's limits."""

import re

import pytest

from tests import misbehaving_laws as laws
from tests.misbehaving_runs import (
    DURATION_S,
    MAX_OUTPUT_MB,
    SAYS,
    bound_s,
    check_recorded,
    failure_window,
    fly,
    law_path,
    the_line,
)
from tests.support import processes_mentioning

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep


@pytest.mark.system
@pytest.mark.parametrize("name", list(SAYS))
@pytest.mark.parametrize("command", ["sim", "run"])
def test_a_misbehaving_law_ends_the_run_in_one_line_or_flies_on(tmp_path, command, name):
    r, wall = fly(tmp_path, command, name)
    out = tmp_path / f"{command}-{name}"
    line = the_line(r)
    says = SAYS[name]
    if says is None:
        assert r.returncode == 0, r.stderr[-2000:]
        check_recorded(out, name, failed=False)
    else:
        assert r.returncode == 1, r.stderr[-2000:]
        assert "\n" not in line and line.startswith("swarm-sitl: error: ")
        found = re.search(rf"law {law_path(command)}:{name}, follower 2 at t=([0-9.]+) s: ", line)
        assert found and says in line, line
        t = float(found[1])
        lo, hi = failure_window(name)
        assert lo - 1e-9 <= t <= hi + 1e-9, line
        if command == "run":  # the tick before the one that failed was its last
            k = round(t / 0.01)
            head = f"swarm-sitl: error: controller_2 exited with code 1 (its last tick {k - 1},"
            assert line.startswith(head), line
        check_recorded(out, name, failed=True)
    assert wall < bound_s(name), wall
    assert not processes_mentioning(str(out))
    if name == "Chatty":  # bounded: the limit, its two lines, and what the process says itself
        log = out / "logs" / ("laws.log" if command == "sim" else "controller_2.log")
        text = log.read_text()
        assert MAX_OUTPUT_MB * 1e6 <= len(text) < MAX_OUTPUT_MB * 1e6 + 2000, len(text)
        printed = (round(DURATION_S / 0.01) + 1) * (len(laws.CHATTER) + 1)
        dropped = int(text.split("[swarm-sitl: ")[-1].split(" bytes")[0])
        assert dropped == printed - MAX_OUTPUT_MB * 1e6
