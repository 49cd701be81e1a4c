"""The fork server starts processes as Popen would: their own pid, session, log, exit code."""

import os
import signal
import sys
import time
from pathlib import Path

import pytest

from swarm_sitl.running.children import PARENT_ENV, child_env, module_argv
from swarm_sitl.running.fork_server import ForkServer

pytestmark = [
    pytest.mark.system,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the fork server is Linux only"),
]


@pytest.fixture
def server(tmp_path):
    env = {**child_env(), PARENT_ENV: str(os.getpid())}
    s = ForkServer(module_argv("swarm_sitl.running.fork_server"), env, tmp_path / "server.log")
    yield s
    s.close()


def _ppid_and_sid(pid: int) -> tuple[int, int]:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[1]), int(fields[3])


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
    ppid, sid = _ppid_and_sid(vehicle.pid)
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
