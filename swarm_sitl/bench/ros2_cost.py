"""``bench --ros2``: what the ROS 2 face costs a lockstep run, measured in one go.

The lockstep ``run`` of the config without and with ``--ros2`` and a ROS 2 reader on it (a zenoh
session of this process that joins the run's router as its ROS 2 user and subscribes to every
ROS 2 topic of the domain, as a ``ros2 topic echo`` of each would; it queues what it gets on
zenoh's side and counts it at the end, so no Python call per message, which would be the
reader's cost and not the face's), alternated ``pairs`` times after one untimed run of each.
Printed: the run phase's wall time (as the CLI prints it) and the CPU of every process (the
reader's included), with and without, and their ratios. The issue's target: with the face at
most 10 % over the run without it. With the face come the leader's ``/clock`` (every tick) and
the followers' states (``nodes.ros2_clock``, ``running.ros2_face``).
"""

import json
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

from swarm_sitl.bench.speed import cpu_now, ended, print_pairs
from swarm_sitl.rundir.layout import ros2_join_path
from swarm_sitl.running.children import child_env, module_argv


def _reader(hub: str, password: str, domain_id: int) -> tuple[Any, Any]:
    import zenoh

    conf = zenoh.Config()
    for key, value in (
        ("mode", "client"),
        ("connect/endpoints", [hub]),
        ("scouting/multicast/enabled", False),
        ("transport/auth/usrpwd/user", "ros2"),
        ("transport/auth/usrpwd/password", password),
    ):
        conf.insert_json5(key, json.dumps(value))
    session = zenoh.open(conf)
    sub = session.declare_subscriber(f"{domain_id}/**", zenoh.handlers.FifoChannel(1_000_000))
    return session, sub


def _run(cfg_path: str, out: Path, ros2: bool) -> tuple[float, float, int]:
    """One lockstep run: its run phase's wall time, the CPU of every process (the reader's too)
    and the ROS 2 messages the reader got."""
    cpu0 = cpu_now()
    argv = [*module_argv("swarm_sitl"), "run", cfg_path, "--quiet", "--out", str(out)]
    argv += ["--ros2"] if ros2 else []
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=child_env())
    reader: Any = None
    heard: Any = None
    if ros2:
        join = ros2_join_path(out)
        end = time.monotonic() + 60
        while not join.is_file() and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.01)
        if join.is_file():
            j = json.loads(join.read_text())
            reader, heard = _reader(
                j["endpoint"], Path(j["password_file"]).read_text().strip(), j["domain_id"]
            )
    stdout, stderr = proc.communicate()
    got = 0
    if reader is not None:
        while heard.try_recv() is not None:
            got += 1
        reader.close()
    wall, cpu = ended(proc.returncode, stdout, stderr, cpu0)
    return wall, cpu, got


def ros2_cost(cfg_path: str, pairs: int) -> int:
    """The run of ``cfg_path`` without and with the ROS 2 face, alternated; prints both and the ratios."""
    got: dict[bool, list[tuple[float, float, int]]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(pairs + 1):
            order = (False, True) if r % 2 == 0 else (True, False)
            for j, ros2 in enumerate(order):
                w = _run(cfg_path, Path(tmp) / f"r{r}_{j}", ros2)
                if r > 0:
                    got[ros2].append(w)
    received = [x[2] for x in got[True]]
    print(
        f"lockstep run of {cfg_path}, without and with --ros2 (a ROS 2 reader on every topic), {pairs} pairs:"
    )
    print(f"  ROS 2 messages the reader got per run: {min(received)}-{max(received)}")
    for what, col in (("run phase wall, as the CLI prints it", 0), ("CPU of every process", 1)):
        without, with_face = [x[col] for x in got[False]], [x[col] for x in got[True]]
        print_pairs(what, ("with", with_face), ("without", without), "with / without")
    print("  target: the run phase with the face at most 10 % over the run without")
    return 0
