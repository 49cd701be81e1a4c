"""The misbehaving laws of ``test_misbehaving_laws.py`` in a real-time run: a follower whose law
fails is named in one line (exit 1) once the swarm has flown on to the end without it
(``run.stop_on_loss: false``, the default: the loss is an event of the run), or at once with
``run.stop_on_loss: true``; the slow law's follower flies on, its late ticks counted; the wall time
is the run's duration plus its limits."""

import json
import re

import numpy as np
import pytest
import yaml

from swarm_sitl.rundir.load import load_run
from tests import misbehaving_laws as laws
from tests.conftest import processes_mentioning
from tests.test_misbehaving_laws import (
    DURATION_S,
    SAYS,
    SLOW_DURATION_S,
    bound_s,
    failure_window,
    fly,
    law_path,
    the_line,
)

#: a real-time tick may come up to a period late, and follower 2's ticks are staggered by 2.5 ms
LATE_S = 0.0125


@pytest.mark.system
@pytest.mark.parametrize("name", list(SAYS))
def test_a_misbehaving_law_in_real_time_is_ridden_through_and_named(tmp_path, name):
    r, wall = fly(tmp_path, "run", name, "--realtime")
    out = tmp_path / f"run-{name}"
    line = the_line(r)
    rec = load_run(out)
    end = rec.followers[1]["t_s"] > rec.followers[1]["t_s"][-1] - 0.1
    assert np.isfinite(rec.followers[1]["p_W"][end]).all()  # the others flew on to the end
    if SAYS[name] is None:
        assert r.returncode == 0, r.stderr[-2000:]
        if name == "Slow":  # 50 ms a tick: most of its 10 ms ticks are skipped, each counted
            report = json.loads((out / "summary.json").read_text())["inputs"]["2"]
            ticks = SLOW_DURATION_S / 0.01
            assert report["late_ticks"] >= 0.5 * ticks and report["max_late_s"] >= laws.SLOW_S, report
    else:
        assert r.returncode == 1, r.stderr[-2000:]
        found = re.search(rf"law {law_path('run')}:{name}, follower 2 at t=([0-9.]+) s: ", line)
        assert found and SAYS[name] in line, line
        assert "(the swarm flew on to the end: run.stop_on_loss false) (partial run in" in line, line
        lo, hi = failure_window(name)
        if name == "Hoards":  # ticks a hoarder is late for are skipped, and allocate nothing
            hi = DURATION_S
        assert lo <= float(found[1]) <= hi + LATE_S, line
        events = [json.loads(x) for x in (out / "procs" / "lost.events").read_text().splitlines()]
        assert [(e["kind"], e["process"], e["code"]) for e in events] == [("process_lost", "controller_2", 1)]
    assert wall < bound_s(name), wall
    assert not processes_mentioning(str(out))


@pytest.mark.system
def test_with_stop_on_loss_a_failing_law_ends_a_real_time_run_at_once(tmp_path):
    """The same exit, and the run ends there: well before the swarm would have ended."""
    from tests.test_misbehaving_laws import config

    path = config(tmp_path, "OsExit", duration_s=20.0)
    data = yaml.safe_load(path.read_text())
    data["run"]["stop_on_loss"] = True
    path.write_text(yaml.safe_dump(data))
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    t0 = time.monotonic()
    r = subprocess.run(
        [sys.executable, "-m", "swarm_sitl", "run", str(path), "--realtime", "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=240,
    )
    wall = time.monotonic() - t0
    line = the_line(r)
    assert r.returncode == 1 and "it called os._exit(3)" in line and "flew on" not in line, line
    rec = load_run(out)
    assert np.isnan(rec.followers[1]["p_W"][rec.followers[1]["t_s"] > 15.0]).all()
    assert wall < 20.0, wall  # the swarm would have flown 20 s
    assert laws.FROM_S < 20.0
    assert not processes_mentioning(str(out))
