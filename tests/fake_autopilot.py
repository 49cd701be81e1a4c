"""A scripted autopilot for the refusal tests: what a real PX4 or ArduCopter says when it will not
do what a controller asks, without simulating one.

``FakeAutopilot`` listens on a UDP port (a controller connects with ``udpout:``), sends the
HEARTBEAT of a PX4 or of an ArduCopter at 1 Hz and a vehicle at rest (LOCAL_POSITION_NED and
ATTITUDE_QUATERNION, at 50 Hz or what MAV_CMD_SET_MESSAGE_INTERVAL asks), answers
PARAM_REQUEST_READ and PARAM_SET from its table (a parameter it lacks: no answer, as both
autopilots give none), and answers commands as scripted: ``refuse_mode`` (DO_SET_MODE FAILED, with
ArduCopter's STATUSTEXT), ``never_arm`` (ARM_DISARM FAILED with a pre-arm STATUSTEXT),
``reboot_after_s`` (that long after it armed, its clock starts again from 0, disarmed),
``busy_mode`` (DO_SET_MODE TEMPORARILY_REJECTED that many times, as PX4 answers OFFBOARD without a
setpoint stream; -1: always), ``read_only`` (parameters a PARAM_SET does not change: answered with
the value kept), ``deaf`` (commands it never answers). ``heard`` keeps every message it
received, in order. Run alone
(``python -m tests.fake_autopilot ...``) it prints ``listening on udp:HOST:PORT`` and serves until
killed.
"""

import argparse
import os
import socket
import sys
import threading
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mav

ARDUPILOT_PARAMS = {"MOT_THST_HOVER": 0.35, "GUID_OPTIONS": 0.0, "ATC_ANGLE_BOOST": 1.0}
PX4_PARAMS = {"MPC_THR_HOVER": 0.5}


class FakeAutopilot:
    def __init__(
        self,
        kind: str,
        system_id: int,
        params: dict[str, float] | None = None,
        refuse_mode: bool = False,
        never_arm: bool = False,
        reboot_after_s: float | None = None,
        port: int = 0,
        busy_mode: int = 0,
        read_only: frozenset[str] = frozenset(),
        deaf: frozenset[int] = frozenset(),
    ):
        self.kind, self.system_id = kind, system_id
        default = ARDUPILOT_PARAMS if kind == "ardupilot" else PX4_PARAMS
        self.params = dict(default if params is None else params)
        self.refuse_mode, self.never_arm, self.reboot_after_s = refuse_mode, never_arm, reboot_after_s
        self.busy_mode, self.read_only, self.deaf = busy_mode, read_only, deaf
        self.heard: list = []
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.01)
        self.port = self.sock.getsockname()[1]
        self.mav = mav.MAVLink(None, srcSystem=system_id, srcComponent=1)
        self.mav.robust_parsing = True
        self.parser = mav.MAVLink(None)
        self.parser.robust_parsing = True
        self.peer: tuple[str, int] | None = None
        self.boot = time.monotonic()
        self.armed_at: float | None = None
        self.mode = 0
        self.sample_every_s = 0.02
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.serve, daemon=True)

    # -- send ----------------------------------------------------------------------------------
    def _send(self, msg: object) -> None:
        if self.peer is not None:
            self.sock.sendto(msg.pack(self.mav), self.peer)  # type: ignore[attr-defined]

    def _ms(self) -> int:
        return int((time.monotonic() - self.boot) * 1000)

    def _heartbeat(self) -> None:
        armed = mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed_at is not None else 0
        autopilot = {"ardupilot": mav.MAV_AUTOPILOT_ARDUPILOTMEGA, "px4": mav.MAV_AUTOPILOT_PX4}.get(
            self.kind, mav.MAV_AUTOPILOT_GENERIC
        )
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | armed
        self._send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, autopilot, base, self.mode, 4, 3))

    def _sample(self) -> None:
        ms = self._ms()
        self._send(mav.MAVLink_local_position_ned_message(ms, 0.0, 0.0, -10.0, 0.0, 0.0, 0.0))
        self._send(
            mav.MAVLink_attitude_quaternion_message(ms, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, [0, 0, 0, 0])
        )

    def _param(self, name: str) -> None:
        self._send(
            mav.MAVLink_param_value_message(
                name.encode(), float(self.params[name]), mav.MAV_PARAM_TYPE_REAL32, len(self.params), 0
            )
        )

    def _text(self, text: str) -> None:
        self._send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_CRITICAL, text.encode()))

    def _ack(self, command: int, result: int, to: object) -> None:
        self._send(
            mav.MAVLink_command_ack_message(command, result, 0, 0, to.get_srcSystem(), to.get_srcComponent())  # type: ignore[attr-defined]
        )

    # -- receive -------------------------------------------------------------------------------
    def _handle(self, m: object) -> None:
        t = m.get_type()  # type: ignore[attr-defined]
        if t == "PARAM_REQUEST_READ" and m.param_id in self.params:  # type: ignore[attr-defined]
            self._param(m.param_id)  # type: ignore[attr-defined]
        elif t == "PARAM_SET" and m.param_id in self.params:  # type: ignore[attr-defined]
            if m.param_id not in self.read_only:  # type: ignore[attr-defined]
                self.params[m.param_id] = float(m.param_value)  # type: ignore[attr-defined]
            self._param(m.param_id)  # type: ignore[attr-defined]
        elif t == "COMMAND_LONG":
            self._command(m)

    def _command(self, m: object) -> None:
        cmd = m.command  # type: ignore[attr-defined]
        if cmd in self.deaf:
            return
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            if m.param1 == mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED and m.param2 > 0:  # type: ignore[attr-defined]
                self.sample_every_s = m.param2 / 1e6  # type: ignore[attr-defined]
            self._ack(cmd, mav.MAV_RESULT_ACCEPTED, m)
        elif cmd == mav.MAV_CMD_DO_SET_MODE:
            if self.busy_mode:
                self.busy_mode -= 1 if self.busy_mode > 0 else 0
                self._ack(cmd, mav.MAV_RESULT_TEMPORARILY_REJECTED, m)
            elif self.refuse_mode:
                self._text("Mode GUIDED_NOGPS failed: requires position")
                self._ack(cmd, mav.MAV_RESULT_FAILED, m)
            else:
                self.mode = int(m.param2) if self.kind == "ardupilot" else (int(m.param2) << 16)  # type: ignore[attr-defined]
                self._ack(cmd, mav.MAV_RESULT_ACCEPTED, m)
        elif cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if self.never_arm and m.param1 >= 0.5:  # type: ignore[attr-defined]
                self._text("PreArm: Throttle below failsafe")
                self._ack(cmd, mav.MAV_RESULT_FAILED, m)
            else:
                self.armed_at = time.monotonic() if m.param1 >= 0.5 else None  # type: ignore[attr-defined]
                self._ack(cmd, mav.MAV_RESULT_ACCEPTED, m)
        elif cmd == mav.MAV_CMD_REQUEST_MESSAGE:
            self._ack(cmd, mav.MAV_RESULT_ACCEPTED, m)
            self._sample()
        else:
            self._ack(cmd, mav.MAV_RESULT_UNSUPPORTED, m)

    def serve(self) -> None:
        next_hb = next_sample = 0.0
        while not self.stop.is_set():
            now = time.monotonic()
            rebooting = self.reboot_after_s is not None and self.armed_at is not None
            if rebooting and now - self.armed_at > self.reboot_after_s:  # type: ignore[operator]
                # a reboot: its clock from 0, disarmed
                self.boot, self.armed_at, self.mode, self.reboot_after_s = now, None, 0, None
            if now >= next_hb:
                self._heartbeat()
                next_hb = now + 1.0
            if now >= next_sample:
                self._sample()
                next_sample = now + self.sample_every_s
            try:
                data, addr = self.sock.recvfrom(4096)
            except (TimeoutError, OSError):
                continue
            self.peer = addr
            for byte_msg in self.parser.parse_buffer(data) or []:
                self.heard.append(byte_msg)
                self._handle(byte_msg)

    def __enter__(self) -> "FakeAutopilot":
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(5)
        self.sock.close()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--kind", choices=("px4", "ardupilot"), required=True)
    ap.add_argument("--id", type=int, required=True)
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--refuse-mode", action="store_true")
    ap.add_argument("--never-arm", action="store_true")
    ap.add_argument("--reboot-after-s", type=float)
    ap.add_argument("--without", nargs="*", default=[], help="parameters it does not have")
    a = ap.parse_args()
    fake = FakeAutopilot(a.kind, a.id, None, a.refuse_mode, a.never_arm, a.reboot_after_s, a.port)
    for name in a.without:
        fake.params.pop(name, None)
    print(f"listening on udp:127.0.0.1:{fake.port}", flush=True)
    fake.serve()
    return 0


if __name__ == "__main__":
    sys.exit(main())
