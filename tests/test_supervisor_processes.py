"""How the supervisor starts and ends its children: each in its own session with its output in
its log and the environment its process is given, a run's vehicles and nodes forked from its fork
server, and at the end a grace for each to finish on SIGTERM before it is killed."""

import os
import signal
import sys
import time
from pathlib import Path

import pytest

from swarm_sitl.running.children import PARENT_ENV, child_env, module_argv
from swarm_sitl.running.fork_server import ForkServer
from swarm_sitl.running.supervisor import Child, RunFailedError, Supervisor
from tests.support import ppid_and_sid

pytestmark = pytest.mark.integration


def _environ(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes()
    return dict(kv.split("=", 1) for kv in raw.decode(errors="replace").split("\0") if "=" in kv)


def test_a_child_is_its_own_session_with_its_environment_and_all_it_says_in_its_log(tmp_path, capfd):
    """In a run directory not made yet: each child's stdout and stderr go to
    ``logs/<name>.log`` (nothing to the terminal), even the lines of a child killed before it
    flushed; it reads no terminal; it is the leader of its own session (a signal to its group
    reaches no one else); its environment names this process as its parent and has what the run
    gives its process (an incarnation gets its process's)."""
    run_dir = tmp_path / "runs" / "r1"
    sup = Supervisor(run_dir, env_for=lambda process: {"SWARM_SITL_TEST_FOR": process})
    says = (
        "import os, signal, sys\n"
        "print('out: ' + repr(sys.stdin.read()))\n"
        "print('err: a line on stderr', file=sys.stderr)\n"
        "os.kill(os.getpid(), signal.SIGSTOP)\n"  # (looked at while stopped, then killed)
    )
    try:
        a = sup.spawn("vehicle_7", [sys.executable, "-c", says], False)
        b = sup.spawn("controller_2.1", [sys.executable, "-c", says], True, "controller_2")
        end = time.monotonic() + 20
        while not (a.stopped() and b.stopped()):
            assert time.monotonic() < end and a.proc.poll() is None and b.proc.poll() is None
            time.sleep(0.02)
        for child, process in ((a, "vehicle_7"), (b, "controller_2")):
            env = _environ(child.pid)
            assert env[PARENT_ENV] == str(os.getpid()) and env["SWARM_SITL_TEST_FOR"] == process
            assert ppid_and_sid(child.pid) == (os.getpid(), child.pid)
            os.kill(child.pid, signal.SIGKILL)
            child.proc.wait(timeout=10)
            assert child.log_path == run_dir / "logs" / f"{child.name}.log"
            assert child.log_path.read_text().splitlines() == ["out: ''", "err: a line on stderr"]
            assert not child.stopped()  # gone: not stopped
    finally:
        sup.close()
    assert capfd.readouterr() == ("", "")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the fork server is Linux only")
def test_a_runs_modules_are_forked_from_its_fork_server_with_their_environment_and_any_other_command_is_not(
    tmp_path,
):
    """With a fork server, a vehicle or a node (``python -P -m sim_vehicles|swarm_sitl.nodes``)
    is the server's child, with the environment the run gives its process (here: where to write
    its profile, which a vehicle does when it has flown its duration); any other command is
    this process's own child; a child the server could not start (its log cannot be opened) fails
    the run with the server's reason."""
    # a new interpreter: forked from this one, which other tests have used, a child could
    # inherit a lock another thread held
    server = ForkServer(
        module_argv("swarm_sitl.running.fork_server"),
        {**child_env(), PARENT_ENV: str(os.getpid())},
        tmp_path / "server.log",
    )
    profiles = tmp_path / "profiles"  # where a vehicle given SWARM_SITL_PROFILE writes its profile
    sup = Supervisor(
        tmp_path, env_for=lambda process: {"SWARM_SITL_PROFILE": str(profiles / process)}, fork_server=server
    )
    try:
        vehicle = sup.spawn(
            "vehicle_3", [*module_argv("sim_vehicles"), "--id", "3", "--port", "0", "--duration", "4"], False
        )
        other = sup.spawn("vehicle_4", [sys.executable, "-c", "import time; time.sleep(60)"], False)
        assert vehicle.pid > 0  # the server's answer: from here its log exists
        end = time.monotonic() + 60
        while "listening on udp:127.0.0.1:" not in vehicle.log_path.read_text():
            assert vehicle.proc.poll() is None and time.monotonic() < end, vehicle.log_path.read_text()
            time.sleep(0.05)
        assert ppid_and_sid(vehicle.pid) == (server.proc.pid, vehicle.pid)
        assert ppid_and_sid(other.pid)[0] == os.getpid()
        (tmp_path / "logs" / "vehicle_5.log").mkdir()  # a log that cannot be opened
        sup.spawn("vehicle_5", [*module_argv("sim_vehicles"), "--id", "5", "--port", "0"], False)
        end = time.monotonic() + 30
        while sup.children[-1].proc.poll() is None:
            assert time.monotonic() < end
            time.sleep(0.02)
        with pytest.raises(
            RunFailedError, match=r"^vehicle_5 exited with code 1: cannot open .*vehicle_5.log:"
        ):
            sup.check()
        assert vehicle.proc.wait(timeout=60) == 0  # its duration flown: it ends by itself
    finally:
        sup.close()
    assert vehicle.proc.poll() is not None and other.proc.poll() is not None
    assert [p.name for p in (profiles / "vehicle_3").iterdir()] == ["vehicle_3.prof"]  # its environment's


class _Vanished:
    """A child's process that ended between the supervisor's look and its signal."""

    pid = 2**22 + 1
    args = "gone"

    def poll(self) -> int | None:
        return None

    def send_signal(self, sig: int) -> None:
        raise ProcessLookupError

    def wait(self, timeout: float | None = None) -> int:
        return 0


def test_closing_lets_a_child_finish_on_sigterm_within_the_grace_and_kills_only_after_it(
    tmp_path, monkeypatch
):
    """A child that takes a moment to write its records after SIGTERM is waited for, and ends
    by its own hand; each that ignores SIGTERM is killed once the one grace has passed, not later; one
    gone before its signal is no error and does not keep the others from being closed."""
    import swarm_sitl.running.supervisor as supervisor

    grace = 1.5
    monkeypatch.setattr(supervisor, "TERM_GRACE_S", grace)
    sup = Supervisor(tmp_path)
    slow = (
        "import pathlib, signal, sys, time\n"
        "def end(*a):\n"
        "    time.sleep(0.4)\n"
        "    print('records written', flush=True)\n"
        "    sys.exit(0)\n"
        "signal.signal(signal.SIGTERM, end)\n"
        "print('up', flush=True)\n"
        "time.sleep(60)\n"
    )
    stubborn = (
        "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); "
        "time.sleep(60)"
    )
    gone = Child("vehicle_9", _Vanished(), tmp_path / "none.log", False)  # type: ignore[arg-type]
    sup.children.append(gone)
    writer = sup.spawn("controller_1", [sys.executable, "-c", slow], True)
    deaf = [sup.spawn(f"vehicle_{i}", [sys.executable, "-c", stubborn], False) for i in (2, 3)]
    end = time.monotonic() + 20
    while any(c.last_line() != "up" for c in [writer, *deaf]):
        assert time.monotonic() < end
        time.sleep(0.02)
    t0 = time.monotonic()
    sup.close()
    took = time.monotonic() - t0
    assert writer.proc.poll() == 0 and writer.last_line() == "records written"
    assert [c.proc.poll() for c in deaf] == [-signal.SIGKILL] * 2
    # one grace for all: waiting for the second deaf one again would take a second grace (the
    # bound is that, not a guess at how fast a loaded machine kills and reaps three processes)
    assert grace <= took < 2 * grace
