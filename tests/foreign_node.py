"""A follower's controller written without swarm-sitl, pymavlink or numpy: only ``zenoh``,
``struct`` and the standard library, from ``docs/bus.md`` alone, as a C++ or Rust node would be.

    python tests/foreign_node.py RUN_DIR/external.json --id 3 --offset -2 -2 0 --duration 20

It meets its vehicle over MAVLink 2 (hand-framed: heartbeat, message rates, arm, OFFBOARD, then
one SET_ATTITUDE_TARGET per tick; signing must be off), joins the bus with the credentials
``run --external`` wrote, declares its liveliness token, waits for the start signal, and each tick
reads the newest message on its in-edges, flies a PD loop on the leader's reference (its offset
in the formation added) and publishes, on each out-edge, the reference carried to its tick: for
the paper's law an exact estimate of the leader's state (12 floats). ``tests/test_foreign_node.py``
runs it in place of one controller of a real-time run.
"""

import argparse
import json
import math
import socket
import struct
import sys
import time
import zlib

import zenoh

# -- MAVLink 2, by hand ---------------------------------------------------------------------------
# (message id, CRC_EXTRA, payload layout): from the MAVLink common.xml definitions, wire order
HEARTBEAT = (0, 50, struct.Struct("<IBBBBB"))
COMMAND_LONG = (76, 152, struct.Struct("<7fHBBB"))
COMMAND_ACK = (77, 143, struct.Struct("<HB"))
SET_ATTITUDE_TARGET = (82, 49, struct.Struct("<I4f4fBBB"))
LOCAL_POSITION_NED = (32, 185, struct.Struct("<I6f"))
ATTITUDE_QUATERNION = (31, 246, struct.Struct("<I7f"))
EXTRA = {
    m[0]: m[1]
    for m in (
        HEARTBEAT,
        COMMAND_LONG,
        COMMAND_ACK,
        SET_ATTITUDE_TARGET,
        LOCAL_POSITION_NED,
        ATTITUDE_QUATERNION,
    )
}
ARM, SET_MODE, SET_INTERVAL = 400, 176, 511
PX4_BASE_FLAGS, PX4_OFFBOARD = 29, 6  # base_mode flags, PX4 main mode OFFBOARD (px4_custom_mode.h)


def x25(data: bytes, crc: int = 0xFFFF) -> int:
    for b in data:
        t = b ^ (crc & 0xFF)
        t = (t ^ (t << 4)) & 0xFF
        crc = ((crc >> 8) ^ (t << 8) ^ (t << 3) ^ (t >> 4)) & 0xFFFF
    return crc


class Mav:
    def __init__(self, host: str, port: int, sysid: int, target: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.peer = (host, port)
        self.sysid, self.target, self.seq = sysid, target, 0
        self.position = None  # (time_boot_ms, x, y, z, vx, vy, vz) NED
        self.attitude = None  # (time_boot_ms, w, x, y, z, ...) FRD -> NED
        self.heard = False
        self.acks: dict[int, int] = {}

    def send(self, msg: tuple, *fields) -> None:
        msgid, extra, layout = msg
        payload = layout.pack(*fields).rstrip(b"\0") or b"\0"  # MAVLink 2 trims trailing zeros
        head = struct.pack("<BBBBBBB", len(payload), 0, 0, self.seq & 0xFF, self.sysid, 191, msgid & 0xFF)
        head += struct.pack("<H", msgid >> 8)
        crc = x25(bytes([extra]), x25(head + payload))
        self.sock.sendto(b"\xfd" + head + payload + struct.pack("<H", crc), self.peer)
        self.seq += 1

    def read(self) -> None:
        while True:
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                return
            while len(data) >= 12 and data[0] == 0xFD:
                n, incompat = data[1], data[2]
                size = 12 + n + (13 if incompat & 1 else 0)
                frame, data = data[:size], data[size:]
                msgid = frame[7] | frame[8] << 8 | frame[9] << 16
                if (
                    msgid not in EXTRA
                    or len(frame) < 12 + n
                    or x25(bytes([EXTRA[msgid]]), x25(frame[1 : 10 + n]))
                    != struct.unpack_from("<H", frame, 10 + n)[0]
                ):
                    continue
                body = frame[10 : 10 + n].ljust(64, b"\0")  # receivers restore trimmed zeros
                if msgid == HEARTBEAT[0]:
                    self.heard = True
                elif msgid == LOCAL_POSITION_NED[0]:
                    self.position = LOCAL_POSITION_NED[2].unpack_from(body)
                elif msgid == ATTITUDE_QUATERNION[0]:
                    self.attitude = ATTITUDE_QUATERNION[2].unpack_from(body)
                elif msgid == COMMAND_ACK[0]:
                    cmd, result = COMMAND_ACK[2].unpack_from(body)
                    self.acks[cmd] = result

    def heartbeat(self) -> None:
        self.send(HEARTBEAT, 0, 18, 8, 0, 4, 3)  # onboard controller, no autopilot, active

    def command(self, command: int, *params: float, before=None, timeout_s: float = 10.0) -> None:
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.acks.pop(command, None)
        end = time.monotonic() + timeout_s
        while self.acks.get(command) != 0:
            if time.monotonic() > end:
                sys.exit(f"foreign node: command {command} not accepted ({self.acks.get(command)})")
            if before is not None:
                before()
            self.send(COMMAND_LONG, *p, command, self.target, 1, 0)
            self.heartbeat()
            time.sleep(0.1)
            self.read()

    def setpoint(self, q_frd_ned, thrust_01: float, time_boot_ms: int = 0) -> None:
        self.send(SET_ATTITUDE_TARGET, time_boot_ms, *q_frd_ned, 0.0, 0.0, 0.0, thrust_01, self.target, 1, 0)


# -- the bus (docs/bus.md) ----------------------------------------------------------------------
MESSAGE_HEAD = struct.Struct("<BHId3dH")  # version, src, step, t_s, position (ENU), value count
VERSION = 4


def encode(src: int, step: int, t_s: float, values: list[float], p_enu: tuple = (0.0, 0.0, 0.0)) -> bytes:
    body = MESSAGE_HEAD.pack(VERSION, src, step, t_s, *p_enu, len(values))
    body += struct.pack(f"<{len(values)}d", *values)
    return body + struct.pack("<I", zlib.crc32(body))


def decode(data: bytes):
    if len(data) < MESSAGE_HEAD.size + 4:
        return None
    version, src, step, t_s, _, _, _, n = MESSAGE_HEAD.unpack_from(data)
    if version != VERSION or len(data) != MESSAGE_HEAD.size + 8 * n + 4:
        return None
    if zlib.crc32(data[:-4]) != struct.unpack_from("<I", data, len(data) - 4)[0]:
        return None
    return src, step, t_s, struct.unpack_from(f"<{n}d", data, MESSAGE_HEAD.size)


# -- the law: PD on the leader's reference, attitude from the force (NED, FRD) ------------------
def quat_of(b1, b2, b3):
    """[w, x, y, z] of the rotation whose columns are b1, b2, b3."""
    m = ((b1[0], b2[0], b3[0]), (b1[1], b2[1], b3[1]), (b1[2], b2[2], b3[2]))
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = 2 * math.sqrt(1 + tr)
        return (s / 4, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s)
    i = max(range(3), key=lambda k: m[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2 * math.sqrt(1 + m[i][i] - m[j][j] - m[k][k])
    q = [0.0] * 4
    q[0] = (m[k][j] - m[j][k]) / s
    q[1 + i] = s / 4
    q[1 + j] = (m[j][i] + m[i][j]) / s
    q[1 + k] = (m[k][i] + m[i][k]) / s
    return tuple(q)


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def unit(a):
    n = math.sqrt(sum(x * x for x in a))
    return tuple(x / n for x in a)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("external_json")
    ap.add_argument("--id", type=int, required=True)
    ap.add_argument("--offset", type=float, nargs=3, required=True, help="formation offset [m; ENU]")
    ap.add_argument("--duration", type=float, required=True)
    ap.add_argument("--mass", type=float, default=0.85)
    ap.add_argument("--max-thrust", type=float, default=25.0)
    ap.add_argument("--out-edges", type=int, nargs="*", default=[])
    ap.add_argument("--in-edges", type=int, nargs="*", default=[0])
    a = ap.parse_args()
    with open(a.external_json) as f:
        info = json.load(f)
    me = info["controllers"][str(a.id)]
    swarm, dt = info["swarm"], info["control_dt_s"]

    host, port = me["mavlink"].removeprefix("udp:").rsplit(":", 1)
    mav = Mav(host, int(port), a.id, a.id)
    end = time.monotonic() + 20
    while not mav.heard:
        if time.monotonic() > end:
            sys.exit("foreign node: no heartbeat from the vehicle")
        mav.heartbeat()
        time.sleep(0.1)
        mav.read()
    for msgid in (LOCAL_POSITION_NED[0], ATTITUDE_QUATERNION[0]):
        mav.command(SET_INTERVAL, float(msgid), dt * 1e6)
    mav.command(ARM, 1.0)
    hover = (1.0, 0.0, 0.0, 0.0), a.mass * 9.81 / a.max_thrust
    mav.command(SET_MODE, float(PX4_BASE_FLAGS), float(PX4_OFFBOARD), before=lambda: mav.setpoint(*hover))

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(info["zenoh"]["mode"]))
    conf.insert_json5("connect/endpoints", json.dumps(info["zenoh"]["connect"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if me.get("zenoh_user"):
        conf.insert_json5(
            "transport/auth/usrpwd", json.dumps({"user": me["zenoh_user"], "password": me["zenoh_password"]})
        )
    session = zenoh.open(conf)
    inbox: dict[int, tuple] = {}
    subs = [
        session.declare_subscriber(f"swarm/{swarm}/edge/{s}/{a.id}", zenoh.handlers.RingChannel(8))
        for s in a.in_edges
    ]
    start = session.declare_subscriber(f"swarm/{swarm}/start", zenoh.handlers.RingChannel(1))
    pubs = {d: session.declare_publisher(f"swarm/{swarm}/edge/{a.id}/{d}") for d in a.out_edges}
    status = session.declare_publisher(f"swarm/{swarm}/status/{a.id}")
    token = session.liveliness().declare_token(f"swarm/{swarm}/alive/{a.id}")

    epoch = None
    while epoch is None:  # hold the vehicle level until the run starts
        s = start.try_recv()
        if s is not None:
            _version, epoch = struct.unpack("<Bd", s.payload.to_bytes())
        mav.setpoint(*hover)
        mav.heartbeat()
        mav.read()
        time.sleep(0.05)
    n = round(a.duration / dt)
    off_ned = (a.offset[1], a.offset[0], -a.offset[2])
    kp, kv, a_max, g = 4.0, 4.0, 5.0, 9.81
    k = 0
    while k <= n:
        wait = epoch + k * dt - time.time()
        if wait > 0:
            time.sleep(wait)
        t = k * dt
        mav.read()
        for sub in subs:
            while (s := sub.try_recv()) is not None:
                m = decode(s.payload.to_bytes())
                if m is not None and (m[0] not in inbox or m[1] > inbox[m[0]][1]):
                    inbox[m[0]] = m
        ref = inbox.get(0)
        if ref is None or mav.position is None:
            mav.setpoint(*hover)
            k += 1
            continue
        _, _, t_r, v = ref
        h = t - t_r  # carry the reference to this tick (its jerk known)
        p_r = [v[i] + h * v[3 + i] + h * h / 2 * v[6 + i] + h**3 / 6 * v[9 + i] for i in range(3)]
        v_r = [v[3 + i] + h * v[6 + i] + h * h / 2 * v[9 + i] for i in range(3)]
        a_r = [v[6 + i] + h * v[9 + i] for i in range(3)]
        ned = lambda e: (e[1], e[0], -e[2])  # noqa: E731  ENU <-> NED (its own inverse)
        p, vel = mav.position[1:4], mav.position[4:7]
        for pub in pubs.values():
            pub.put(encode(a.id, k, t, [*p_r, *v_r, *a_r, *v[9:12]], ned(p)))
        pr, vr, ar = ned(p_r), ned(v_r), ned(a_r)
        acc = [ar[i] + kp * (pr[i] + off_ned[i] - p[i]) + kv * (vr[i] - vel[i]) for i in range(3)]
        norm = math.sqrt(sum(x * x for x in acc))
        if norm > a_max:
            acc = [x * a_max / norm for x in acc]
        F = [a.mass * acc[0], a.mass * acc[1], a.mass * (acc[2] - g)]  # NED: gravity is +z
        b3 = unit([-x for x in F])  # FRD z points against the thrust
        b2 = unit(cross(b3, (1.0, 0.0, 0.0)))  # heading north
        b1 = cross(b2, b3)
        thrust = math.sqrt(sum(x * x for x in F)) / a.max_thrust
        mav.setpoint(quat_of(b1, b2, b3), min(max(thrust, 0.0), 1.0))
        if k % 10 == 0:
            mav.heartbeat()
            status.put(struct.pack("<BHIdd3d", VERSION, a.id, k, t, t, p[1], p[0], -p[2]))
        k += 1
    token.undeclare()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
