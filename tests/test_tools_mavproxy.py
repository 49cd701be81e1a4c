"""MAVProxy (from PyPI, unchanged) against a vehicle process: what a user types, and what it prints.

MAVProxy runs headless (``--nowait``) with its commands on stdin, as a user would type them; the
test waits for each answer in what it prints. Skipped, with the reason, where MAVProxy is not
installed (it is in the ``test`` extra).
"""

import contextlib
import queue
import re
import shutil
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from tests.support import free_udp_port, spawn_vehicle

pytestmark = pytest.mark.system
MAVPROXY = shutil.which("mavproxy.py") or str(
    __import__("pathlib").Path(sys.executable).with_name("mavproxy.py")
)


class Console:
    """MAVProxy's stdin and stdout, line by line."""

    def __init__(self, argv: list[str], cwd):
        self.proc = subprocess.Popen(
            argv, cwd=cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def type(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def expect(self, pattern: str, timeout_s: float = 15.0) -> re.Match:
        end = time.monotonic() + timeout_s
        while True:
            for line in self.seen:
                if m := re.search(pattern, line):
                    self.seen = self.seen[self.seen.index(line) + 1 :]
                    return m
            left = end - time.monotonic()
            assert left > 0, f"MAVProxy never printed {pattern!r}; it printed: {self.seen[-20:]}"
            with contextlib.suppress(queue.Empty):
                self.seen.append(self.lines.get(timeout=left))

    def close(self) -> None:
        if self.proc.poll() is None:
            self.type("exit")
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


@pytest.fixture
def vehicle_ports(tmp_path):
    """A vehicle speaking as PX4 and one speaking as ArduCopter, each on its own port."""
    pytest.importorskip("MAVProxy", reason="MAVProxy is not installed (pip install '.[test]')")
    ports = {"px4": free_udp_port(), "ardupilot": free_udp_port()}
    procs = [spawn_vehicle(1, ports[kind], "--autopilot", kind) for kind in ports]
    yield ports
    for proc in procs:
        proc.terminate()
        proc.wait(timeout=10)


def _set_and_see(con: Console, name: str, value: float) -> None:
    """``param set``, then ``param show`` until MAVProxy's table has what the vehicle answered."""
    con.type(f"param set {name} {value:g}")
    end = time.monotonic() + 10  # the vehicle's PARAM_VALUE answer updates MAVProxy's table
    while True:
        con.type(f"param show {name}")
        if float(con.expect(rf"{name}\s+([0-9.]+)").group(1)) == value:
            return
        assert time.monotonic() < end, f"{name} never changed"
        time.sleep(0.2)


def _px4_session(vehicle_port: int, cwd) -> None:
    """MAVProxy on the PX4 profile: the mode from the heartbeat, PX4's parameters, position,
    arming, OFFBOARD's rule and a mode it does not have."""
    con = Console([MAVPROXY, f"--master=udpout:127.0.0.1:{vehicle_port}", "--nowait"], cwd)
    try:
        con.expect(r"Detected vehicle 1:1")
        con.expect(r"Mode LOITER")  # PX4's Hold, by name, from the heartbeat
        con.expect(r"Received 6 parameters")  # PX4's names only (vehicle.autopilots.px4_params)
        con.type("param show MPC_THR_HOVER")  # the hover thrust: m g / T_max of the paper's vehicle
        hover = float(con.expect(r"MPC_THR_HOVER\s+([0-9.]+)").group(1))
        assert hover == pytest.approx(0.85 * 9.81 / 25.0, rel=1e-5)
        _set_and_see(con, "COM_OF_LOSS_T", 2.0)
        con.type("status GLOBAL_POSITION_INT")
        m = con.expect(r"GLOBAL_POSITION_INT \{.*lat : (\d+), lon : (\d+), .*relative_alt : (-?\d+)")
        assert int(m.group(1)) == 473977420 and int(m.group(2)) == 85455940  # home: PX4 SITL's
        assert int(m.group(3)) == pytest.approx(20000, abs=100)  # 20 m up [mm]
        con.type("arm throttle")
        con.expect(r"COMPONENT_ARM_DISARM: ACCEPTED")
        con.expect(r"ARMED")
        # MAVProxy 1.8.75's "mode OFFBOARD" hands pymavlink a tuple for PX4 and fails before
        # sending; its COMMAND_LONG command sends PX4's mode numbers (base 29, main, sub)
        con.type("long DO_SET_MODE 29 6 0")
        con.expect(r"DO_SET_MODE: TEMPORARILY_REJECTED")  # PX4's rule: no setpoint stream yet
        con.type("long DO_SET_MODE 29 4 6")
        con.expect(r"DO_SET_MODE: DENIED")  # AUTO.LAND: a mode this vehicle does not have
        con.type("long DO_SET_MODE 29 4 3")
        con.expect(r"DO_SET_MODE: ACCEPTED")
        con.type("wp list")
        con.expect(r"Requesting 0 waypoints")
        con.type("status HEARTBEAT")
        m = con.expect(r"HEARTBEAT \{type : 2, autopilot : 12, base_mode : (\d+), custom_mode : (\d+)")
        assert int(m.group(1)) & 128 and int(m.group(2)) == (4 << 16) | (3 << 24)  # armed, Hold
        assert not any("fence breach" in line for line in con.seen)
    finally:
        con.close()


def _arducopter_session(arducopter_port: int, cwd) -> None:
    """MAVProxy, ArduPilot's own ground station, on a vehicle speaking as ArduCopter: it names the
    mode from the heartbeat, lists ArduCopter's modes, ``mode GUIDED_NOGPS`` and ``arm throttle``
    are accepted and show in the heartbeat, ``param show MOT_THST_HOVER`` is the vehicle's hover
    thrust, and ``param set GUID_OPTIONS 8`` takes."""
    con = Console([MAVPROXY, f"--master=udpout:127.0.0.1:{arducopter_port}", "--nowait"], cwd)
    try:
        con.expect(r"Detected vehicle 1:1")
        con.expect(r"Mode STABILIZE")  # ArduCopter's boot mode, by name
        con.expect(r"Received \d+ parameters")
        con.type("mode")
        modes = con.expect(r"Available modes:\s+(.*)").group(1)
        assert {"STABILIZE", "GUIDED", "LAND", "GUIDED_NOGPS"} <= {m.strip() for m in modes.split(",")}
        con.type("param show MOT_THST_HOVER")
        hover = float(con.expect(r"MOT_THST_HOVER\s+([0-9.]+)").group(1))
        assert hover == pytest.approx(0.85 * 9.81 / 25.0, rel=1e-5)
        con.type("param show GUID_OPTIONS")
        assert float(con.expect(r"GUID_OPTIONS\s+([0-9.]+)").group(1)) == 0  # as ArduCopter ships
        _set_and_see(con, "GUID_OPTIONS", 8)
        con.type("mode GUIDED_NOGPS")
        con.expect(r"DO_SET_MODE: ACCEPTED")
        con.expect(r"Mode GUIDED_NOGPS")
        con.type("arm throttle")
        con.expect(r"COMPONENT_ARM_DISARM: ACCEPTED")
        con.expect(r"ARMED")
        con.type("mode AUTO")  # a mode this vehicle does not have: refused as ArduCopter refuses it
        con.expect(r"DO_SET_MODE: FAILED")
        con.type("status HEARTBEAT")
        m = con.expect(r"HEARTBEAT \{type : 2, autopilot : 3, base_mode : (\d+), custom_mode : (\d+)")
        assert int(m.group(1)) & 128 and int(m.group(2)) == 20  # armed, GUIDED_NOGPS
    finally:
        con.close()


def test_mavproxy_on_a_px4_and_on_an_arducopter_vehicle_as_their_users_type_it(vehicle_ports, tmp_path):
    """The two sessions above at once, each MAVProxy in a directory of its own (each answer is
    waited for in what its own MAVProxy prints)."""
    sessions = {"px4": _px4_session, "ardupilot": _arducopter_session}
    with ThreadPoolExecutor(2) as pool:
        done = []
        for kind, session in sessions.items():
            (tmp_path / kind).mkdir()
            done.append(pool.submit(session, vehicle_ports[kind], tmp_path / kind))
        for d in done:
            d.result()  # (a session's failure, raised here)
