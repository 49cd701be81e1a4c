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

import pytest

from tests.test_vehicle_mavlink import _free_udp_port, spawn_vehicle

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
def vehicle_port(tmp_path):
    pytest.importorskip("MAVProxy", reason="MAVProxy is not installed (pip install '.[test]')")
    port = _free_udp_port()
    proc = spawn_vehicle(1, port)
    yield port
    proc.terminate()
    proc.wait(timeout=10)


def test_mavproxy_shows_mode_and_position_reads_and_sets_a_parameter_and_arms(vehicle_port, tmp_path):
    con = Console([MAVPROXY, f"--master=udpout:127.0.0.1:{vehicle_port}", "--nowait"], tmp_path)
    try:
        con.expect(r"Detected vehicle 1:1")
        con.expect(r"Mode LOITER")  # PX4's Hold, by name, from the heartbeat
        con.expect(r"Received 10 parameters")
        con.type("param show MASS_KG")
        assert float(con.expect(r"MASS_KG\s+([0-9.]+)").group(1)) == pytest.approx(0.85)
        con.type("param set SP_TIMEOUT_S 2.0")
        end = time.monotonic() + 10  # the vehicle's PARAM_VALUE answer updates MAVProxy's table
        while True:
            con.type("param show SP_TIMEOUT_S")
            if float(con.expect(r"SP_TIMEOUT_S\s+([0-9.]+)").group(1)) == 2.0:
                break
            assert time.monotonic() < end, "the parameter never changed"
            time.sleep(0.2)
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
