"""How the tests fly a misbehaving law (``tests/misbehaving_laws.py``) and read what came of it:
the config, the run, the bound on its wall time, the one line and the run directory. Shared by
``test_misbehaving_laws`` (sim and lockstep) and ``test_misbehaving_laws_realtime``."""

import json
import math
import re
import subprocess
import time
from pathlib import Path

import numpy as np
import yaml

from swarm_sitl.nodes.law_guard import HARD_STOP_S
from swarm_sitl.rundir.load import load_run
from tests import misbehaving_laws as laws
from tests.support import CONFIGS, cli

LAWS_FILE = Path(laws.__file__)
DURATION_S = 1.2
SLOW_DURATION_S = 0.6  #: the slow law's run: 61 ticks of 50 ms in lockstep
#: the real-time run of three loads at once (``MixedLoads``): 1.5 s of hoarding, not 0.7, since
#: a 1.2 s run on a loaded 2-core CI machine once ended before its hoarder reached its bound
LOADS_DURATION_S = 2.0
TICK_TIMEOUT_S = 1.5
MAX_MEMORY_MB = 150.0
MAX_OUTPUT_MB = 0.2
#: startup (compiled kernels loaded, processes ready) and teardown of a run, on 2 busy cores [s]
START_AND_END_S = 60.0

#: law -> what its one line says after "law <entry>, follower 2 at t=0.5..s: " (None: it flies on)
SAYS = {
    "SysExit": "it called sys.exit(0), which ends nothing here",
    "OsExit": "it called os._exit(3), which ends nothing here",
    "Loops": f"its step did not return within {TICK_TIMEOUT_S:g} s (run.tick_timeout_s)",
    "Hoards": f"past law.max_memory_mb {MAX_MEMORY_MB:g}",
    "Slow": None,
    "Chatty": None,
}


def config(tmp_path: Path, name: str, duration_s: float = DURATION_S) -> Path:
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["duration_s"] = duration_s
    data["law"] = {
        "entry": f"{LAWS_FILE}:{name}",
        "max_memory_mb": MAX_MEMORY_MB,
        "max_output_mb": MAX_OUTPUT_MB,
    }
    data["run"] = {**data.get("run", {}), "tick_timeout_s": TICK_TIMEOUT_S}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def duration_s(name: str) -> float:
    """How long the run of ``name`` flies [s]."""
    return {"Slow": SLOW_DURATION_S, "MixedLoads": LOADS_DURATION_S}.get(name, DURATION_S)


def fly(tmp_path: Path, command: str, name: str, *extra: str) -> tuple[subprocess.CompletedProcess, float]:
    out = tmp_path / f"{command}-{name}"
    duration = duration_s(name)
    argv = [command, config(tmp_path, name, duration), "--out", out, "--quiet", *extra]
    t0 = time.monotonic()
    r = cli(*argv, timeout=240)
    return r, time.monotonic() - t0


def bound_s(name: str) -> float:
    """The wall time a run of ``name`` may take: its ticks (50 ms each for the slow law), the
    guard's timeout and hard stop for the loop, and the run's start and end."""
    ticks = (SLOW_DURATION_S / 0.01 + 1) * laws.SLOW_S if name == "Slow" else DURATION_S
    return ticks + TICK_TIMEOUT_S + HARD_STOP_S + START_AND_END_S


def law_path(command: str) -> str:
    """How the line names the law's file: ``sim`` flies it where it is; ``run`` flies the copy
    its run directory keeps (``rundir.plugins``)."""
    return re.escape(str(LAWS_FILE)) if command == "sim" else rf"\S+/plugins/{LAWS_FILE.name}"


def failure_window(name: str) -> tuple[float, float]:
    """When follower 2's law can fail [s]: at 0.5 s; a hoarder once the process has grown past
    the bound, which its arrays (16 MB a tick from 0.5 s) reach at the 10th tick, or one tick
    sooner with the process's own growth since the guard started (under one array), and at most
    20 ticks later (the guard looks every 50 ms; a tick that allocates 16 MB takes over 2.5 ms)."""
    if name != "Hoards":
        return laws.FROM_S, laws.FROM_S
    first = laws.FROM_S + (math.floor(MAX_MEMORY_MB * 1e6 / laws.HOARD_BYTES) - 1) * 0.01
    return first, first + 0.2


def the_line(r: subprocess.CompletedProcess) -> str:
    line = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else ""
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    return line


def check_recorded(out: Path, name: str, failed: bool) -> None:
    """The run directory reads; follower 2 recorded up to its failure (none after), the others to
    the failure at least."""
    rec = load_run(out)
    t = rec.followers[2]["t_s"]
    p2 = rec.followers[2]["p_W"]
    before = t < laws.FROM_S - 0.05
    assert np.isfinite(p2[before]).all(), name
    if failed:
        assert np.isnan(p2[t > laws.FROM_S + 0.25]).all(), name
    else:
        assert np.isfinite(p2).all(), name
    json.loads((out / "summary.json").read_text())
