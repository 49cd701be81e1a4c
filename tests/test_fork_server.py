"""The fork server starts processes as Popen would: their own pid, session, log, exit code; forked
from its supervisor, it is the same server and runs nothing of the supervisor's."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swarm_sitl.running.children import PARENT_ENV, child_env, module_argv
from swarm_sitl.running.fork_server import ForkServer
from tests.support import CONFIGS, cli_ok, ppid_and_sid

#: (no wall clock to the millisecond here: generous timeouts only, so beside other tests)
pytestmark = [
    pytest.mark.system,
    pytest.mark.lockstep,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the fork server is Linux only"),
]


@pytest.fixture(params=["interpreter", "here"])
def server(tmp_path, request):
    """A server started as a new interpreter, or forked from this process (as ``swarm-sitl run``
    forks its own): every test below holds for both. (Under pytest-xdist this process runs
    execnet's thread, so ``can_fork_here`` would refuse it: the server is forked here anyway, to
    test the mechanism; it touches nothing of that thread's, closing its descriptors and making
    its own standard streams before anything else. The policy is tested in a fresh interpreter,
    below.)"""
    env = {**child_env(), PARENT_ENV: str(os.getpid())}
    argv = module_argv("swarm_sitl.running.fork_server")
    s = ForkServer(argv, env, tmp_path / "server.log", here=request.param == "here")
    yield s
    s.close()


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_children_are_their_own_processes_with_their_exit_codes_and_logs(server, tmp_path):
    env = {**child_env(), "SWARM_SITL_TEST_MARK": "hello"}
    bad = server.spawn("sim_vehicles", ["--id", "0"], env, tmp_path / "bad.log")  # a usage error
    helped = server.spawn("swarm_sitl.nodes", ["--help"], env, tmp_path / "help.log")
    assert bad.wait(timeout=30) == 2
    assert "--id must be 1..255, got 0" in (tmp_path / "bad.log").read_text()
    assert helped.wait(timeout=30) == 0
    assert "python -m swarm_sitl.nodes" in (tmp_path / "help.log").read_text()
    assert len({bad.pid, helped.pid, server.proc.pid, os.getpid()}) == 4


def test_a_child_runs_in_its_own_session_under_the_server_and_reports_its_signal(server, tmp_path):
    # a vehicle listening on a free port runs until it is told to stop
    vehicle = server.spawn("sim_vehicles", ["--id", "3", "--port", "0"], child_env(), tmp_path / "v.log")
    assert vehicle.pid > 0  # the server's answer: from here the log exists
    end = time.monotonic() + 30
    while "listening on udp:127.0.0.1:" not in (tmp_path / "v.log").read_text():
        assert vehicle.poll() is None and time.monotonic() < end, (tmp_path / "v.log").read_text()
        time.sleep(0.05)
    ppid, sid = ppid_and_sid(vehicle.pid)
    assert ppid == server.proc.pid and sid == vehicle.pid  # forked by the server, setsid as Popen's
    os.kill(vehicle.pid, signal.SIGKILL)
    assert vehicle.wait(timeout=10) == -signal.SIGKILL


def test_the_children_die_with_the_server(server, tmp_path):
    vehicle = server.spawn("sim_vehicles", ["--id", "4", "--port", "0"], child_env(), tmp_path / "v.log")
    assert vehicle.pid > 0
    end = time.monotonic() + 30
    while "listening" not in (tmp_path / "v.log").read_text():
        assert time.monotonic() < end
        time.sleep(0.05)
    server.proc.kill()
    server.proc.wait()
    end = time.monotonic() + 10
    while _alive(vehicle.pid):
        assert time.monotonic() < end, "the vehicle outlived its fork server"
        time.sleep(0.05)
    server.pump()
    assert vehicle.poll() == -signal.SIGKILL  # accounted for as gone


def test_a_request_it_cannot_serve_is_refused_and_the_server_serves_on(server, tmp_path):
    refused = server.spawn("swarm_sitl", ["--help"], child_env(), tmp_path / "no" / "such" / "dir.log")
    assert refused.wait(timeout=30) == 1 and "cannot open" in refused.error and refused.pid == -1
    assert server.spawn("swarm_sitl", ["--help"], child_env(), tmp_path / "ok.log").wait(timeout=30) == 0


def test_requests_are_pipelined_and_answered_in_order(server, tmp_path):
    """Ten children asked for at once: each gets its own pid and its own exit code, in order."""
    kids = [
        server.spawn("sim_vehicles", ["--id", str(256 + i)], child_env(), tmp_path / f"{i}.log")
        for i in range(10)
    ]
    assert [k.wait(timeout=30) for k in kids] == [2] * 10
    assert len({k.pid for k in kids}) == 10
    for i in range(10):
        assert f"--id must be 1..255, got {256 + i}" in (tmp_path / f"{i}.log").read_text()


#: a supervisor in a fresh interpreter (one thread, no zenoh): its server forked from it, then
#: whether it could fork with a thread more, and with a zenoh runtime once opened
HERE_SCRIPT = """
import atexit, json, os, sys, tempfile, threading
from pathlib import Path
from swarm_sitl.running.run import start_fork_server
from swarm_sitl.running.fork_server import can_fork_here
from swarm_sitl.running.children import child_env

out = Path(sys.argv[1])
atexit.register(lambda: open(out / "exits", "a").write(str(os.getpid()) + " "))
keep = tempfile.TemporaryDirectory(dir=out)  # its finalizer removes it: the supervisor's only
fresh = can_fork_here()
server = start_fork_server(out / "paper.yaml", out, here=True)
bad = server.spawn("sim_vehicles", ["--id", "0"], child_env(), out / "bad.log")
seen = dict(fresh=fresh, here=type(server.proc).__name__, code=bad.wait(timeout=60), me=os.getpid(),
            title=Path(f"/proc/{server.proc.pid}/cmdline").read_bytes().decode(errors="replace"))
server.close()
seen.update(ended=server.proc.returncode, kept=Path(keep.name).is_dir())
t = threading.Thread(target=threading.Event().wait, args=(2,))
t.start()
seen["threaded"] = can_fork_here()
t.join()
import zenoh
zenoh.open(zenoh.Config()).close()
seen["zenohed"] = can_fork_here()
print(json.dumps(seen))
"""


def test_a_server_forked_from_its_supervisor_runs_none_of_the_supervisors_exit_work(tmp_path):
    """A supervisor of one thread forks its server (``swarm-sitl run``'s way): the server warms up
    on the config, serves, ends with code 0 when told, and the supervisor's exit handler and its
    temporary directory's finalizer ran in the supervisor only, once. With one Python thread
    more, or a zenoh runtime once opened (its threads outlive the session), it may not fork."""
    config = tmp_path / "paper.yaml"
    config.write_text((Path(__file__).resolve().parents[1] / "configs" / "paper.yaml").read_text())
    r = subprocess.run(
        [sys.executable, "-c", HERE_SCRIPT, str(tmp_path)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen["fresh"] and seen["here"] == "_ServerHere" and seen["code"] == 2
    assert "swarm_sitl.running.fork_server" in seen["title"] and str(config) in seen["title"]
    assert seen["ended"] == 0 and seen["kept"]
    assert (tmp_path / "exits").read_text().split() == [str(seen["me"])]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("tmp")]  # gone, by its owner
    assert "--id must be 1..255, got 0" in (tmp_path / "bad.log").read_text()
    assert not seen["threaded"] and not seen["zenohed"]


@pytest.mark.parametrize("quiet", [[], ["--quiet"]])
def test_swarm_sitl_run_forks_its_server_from_itself_with_or_without_its_progress_bar(tmp_path, quiet):
    """The CLI's process opens no zenoh session and starts no thread before its run (its progress
    bar has no monitor thread), so its fork server is forked from it, not a new interpreter."""
    out = tmp_path / "run"
    cli_ok("run", CONFIGS / "paper.yaml", "--duration", "0.5", "--out", out, *quiet)
    log = (out / "logs" / "fork_server.log").read_text().splitlines()
    assert log and log[0].startswith("fork server: forked from its supervisor (pid "), log[:3]
