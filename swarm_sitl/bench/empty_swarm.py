"""An empty swarm: a lockstep swarm's processes and messages with no work in them
(``swarm-sitl bench --scale N,... --empty``).

A lockstep ``run`` of N followers is 2N + 1 processes handing every tick to one another: the
controller's setpoint wakes its vehicle, the vehicle's sample wakes the controller, each estimate
crosses zenoh through the run's router to the out-neighbours. On a small machine what that costs
can outweigh the laws, so ``bench --scale`` can measure it apart: a swarm of the same processes,
exchanging the same messages in the same order on the same graph, doing nothing else. ``sim`` is
the other side: the same laws with no transport.

- a vehicle is a UDP socket that answers each datagram with one the size of a signed sample
  (LOCAL_POSITION_NED and ATTITUDE_QUATERNION);
- a controller is a zenoh client session of the router; at tick k it waits for its vehicle's
  answer and for its in-neighbours' payloads of tick k - 1, puts an estimate-sized payload on
  each out-edge, a status every ``run.status_every`` ticks, and sends a datagram the size of a
  signed SET_ATTITUDE_TARGET;
- the leader puts tick k on its out-edges at most ``run.lockstep_window`` ticks ahead of the
  slowest follower's status, sleeping ``LEADER_POLL_S`` when it is that far ahead;
- the router is a zenoh session in this process, with the run's router runtime
  (``bus.session.ROUTER_RUNTIME``) but neither authentication nor access control.

Every process runs under ``SCHED_BATCH``, as a lockstep run's do, and imports zenoh and little
else; nothing is computed, signed, logged or checked. What it measures is what the structure costs
on this machine, not a bound a run cannot pass (a run's loops differ in detail), and a machine
with more cores moves it.
"""

import contextlib
import json
import select
import socket
import subprocess
import sys
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import zenoh

from sim_vehicles.runtime.lifeline import batch_scheduling
from sim_vehicles.runtime.udp_arrival import block_reads
from swarm_sitl.bus import keys as zenoh_keys

if TYPE_CHECKING:
    from swarm_sitl.config.schema import SwarmConfig

# the processes import this module and zenoh only (each of 2N + 1 starts in a fraction of a second);
# what only the measuring process needs is imported in its functions

SWARM = "empty"
STALL_S = 10.0  #: a process of the empty swarm that waits this long for a message gives up [s]


def _signed_len(*msgs: Any) -> int:
    from pymavlink.dialects.v20 import common as mav

    from sim_vehicles.mavlink.signing import SIGNATURE_LEN

    link = mav.MAVLink(None, 1, 1)
    return sum(len(m.pack(link)) + SIGNATURE_LEN for m in msgs)


def message_sizes() -> tuple[int, int, int]:
    """(sample datagram, setpoint datagram, estimate payload) [bytes], as a signed run sends them."""
    import numpy as np
    from pymavlink.dialects.v20 import common as mav

    from swarm_sitl.bus.codec import Message, encode_message
    from swarm_sitl.laws.contract import REFERENCE_LENGTH

    sample = _signed_len(
        mav.MAVLink_local_position_ned_message(1, 1.5, 2.5, 3.5, 0.1, 0.2, 0.3),
        mav.MAVLink_attitude_quaternion_message(1, 0.9, 0.1, 0.2, 0.3, 0.1, 0.2, 0.3, [0.0] * 4),
    )
    setpoint = _signed_len(
        mav.MAVLink_set_attitude_target_message(1, 1, 1, 0, [0.9, 0.1, 0.2, 0.3], 0.1, 0.2, 0.3, 0.5)
    )
    estimate = len(encode_message(Message(1, 1, 0.01, np.full(REFERENCE_LENGTH, 0.5))))
    return sample, setpoint, estimate


class EmptySwarmError(RuntimeError):
    """The empty swarm could not run (a process failed or stalled); the message is one line."""


@dataclass
class EmptyRun:
    followers: int
    ticks: int
    wall_s: float  #: from the start signal to the last controller's last tick
    cpu_s: dict[str, float]  #: per kind (vehicles, controllers, leader, router), the run phase's
    #: per follower, the payloads taken from each in-neighbour by its last tick (keys: str(node))
    received: dict[int, dict[str, int]]
    answered: dict[int, int]  #: per follower, the datagrams its vehicle answered

    @property
    def cpu_total_s(self) -> float:
        return sum(self.cpu_s.values())


class _Inbox:
    """Samples of some keys, queued by zenoh's thread, with a wake-up byte per batch (as ``bus``)."""

    def __init__(self, session: zenoh.Session, keys: list[str]):
        self.queue: deque[Any] = deque()
        self.r, self._w = socket.socketpair()
        self.r.setblocking(False)
        self._w.setblocking(False)
        self._woken = False
        self._subs = [session.declare_subscriber(k, self._queued) for k in keys]

    def _queued(self, sample: Any) -> None:
        self.queue.append(sample)
        if not self._woken:
            self._woken = True
            with contextlib.suppress(OSError):  # full (the loop wakes anyway) or closed
                self._w.send(b"\0")

    def take(self) -> list[Any]:
        """What has come, in order (the wake-up byte read if one is out)."""
        if self._woken:
            self._woken = False
            with contextlib.suppress(OSError):  # a byte written a moment late: ``wait`` reads it
                self.r.recv(64)
        queue, out = self.queue, []
        while queue:  # popleft: zenoh's thread may append meanwhile
            out.append(queue.popleft())
        return out

    def wait(self) -> None:
        """Block until a wake-up byte comes (and read it: none is left to wake the next wait)."""
        if not select.select([self.r], [], [], STALL_S)[0]:
            raise SystemExit("empty swarm: no message for 10 s")
        with contextlib.suppress(OSError):
            self.r.recv(64)
        self._woken = False


def _client(router: str) -> zenoh.Session:
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([router]))
    c.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(c)


def _ready_then_go(what: str = "") -> float:
    """Say ready (with ``what``) on stdout, wait for the start line on stdin; the CPU clock then."""
    print(f"ready {what}".strip(), flush=True)
    if sys.stdin.readline().strip() != "go":
        raise SystemExit(0)
    return time.process_time()


def _vehicle(sample_bytes: int) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    block_reads(sock, STALL_S)  # a read waits in recvfrom, as a lockstep vehicle's does
    answer = bytes(sample_bytes)
    cpu0 = _ready_then_go(str(sock.getsockname()[1]))
    answered = 0
    while True:
        data, addr = sock.recvfrom(4096)
        if data == b"bye":
            break
        sock.sendto(answer, addr)
        answered += 1
    print(json.dumps({"cpu_s": time.process_time() - cpu0, "answered": answered}), flush=True)


def _controller(i: int, args: dict[str, Any]) -> None:
    session = _client(args["router"])
    inbox = _Inbox(session, [zenoh_keys.edge(SWARM, s, i) for s in args["ins"]])
    pubs = [session.declare_publisher(zenoh_keys.edge(SWARM, i, d)) for d in args["outs"]]
    status = session.declare_publisher(zenoh_keys.status(SWARM, i))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.connect(("127.0.0.1", args["vehicle_port"]))
    block_reads(sock, STALL_S)  # as a lockstep controller waits for its sample
    n, every = args["ticks"], args["status_every"]
    setpoint, estimate = bytes(args["setpoint_bytes"]), bytearray(args["estimate_bytes"])
    have = dict.fromkeys(args["ins"], -1)
    received = dict.fromkeys(args["ins"], 0)
    cpu0 = _ready_then_go()
    sock.send(setpoint)  # the first sample
    for k in range(n + 1):
        sock.recv(4096)
        while True:
            for sample in inbox.take():
                b = sample.payload.to_bytes()
                src, step = b[0], int.from_bytes(b[1:5], "little")
                have[src] = max(have[src], step)
                received[src] += 1
            if all(step >= k - 1 for step in have.values()):
                break
            inbox.wait()
        estimate[0], estimate[1:5] = i, k.to_bytes(4, "little")
        payload = bytes(estimate)
        for p in pubs:
            p.put(payload)
        if k % every == 0 or k == n:
            status.put(k.to_bytes(4, "little"))
        if k < n:
            sock.send(setpoint)
    cpu = time.process_time() - cpu0
    sock.send(b"bye")
    print(json.dumps({"cpu_s": cpu, "received": received}), flush=True)
    time.sleep(0.5)  # its last payloads reach the others before the session closes
    session.close()


def _leader(args: dict[str, Any]) -> None:
    session = _client(args["router"])
    pubs = [session.declare_publisher(zenoh_keys.edge(SWARM, 0, d)) for d in args["outs"]]
    followers = args["followers"]
    statuses = _Inbox(session, [zenoh_keys.status(SWARM, f) for f in followers])
    progress = dict.fromkeys(followers, 0)
    n, window = args["ticks"], args["window"]
    estimate = bytearray(args["estimate_bytes"])
    cpu0 = _ready_then_go()
    k = 0
    while k <= n:
        for sample in statuses.take():
            f = int(str(sample.key_expr).rsplit("/", 1)[1])
            progress[f] = int.from_bytes(sample.payload.to_bytes(), "little")
        if k > min(progress.values()) + window:
            time.sleep(args["poll_s"])
            continue
        estimate[0], estimate[1:5] = 0, k.to_bytes(4, "little")
        payload = bytes(estimate)
        for p in pubs:
            p.put(payload)
        k += 1
    print(json.dumps({"cpu_s": time.process_time() - cpu0}), flush=True)
    time.sleep(0.5)
    session.close()


def _spawn(role: str, args: dict[str, Any]) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-P", "-m", "swarm_sitl.bench.empty_swarm", role, json.dumps(args)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )


def _line(p: subprocess.Popen[str], what: str) -> str:
    assert p.stdout is not None
    line = p.stdout.readline()
    if not line:
        raise EmptySwarmError(f"empty swarm: a {what} process exited with code {p.wait()}")
    return line.strip()


def measure_empty(cfg: "SwarmConfig", ticks: int) -> EmptyRun:
    """The empty swarm of ``cfg``'s graph for ``ticks`` lockstep ticks (the module doc)."""
    from swarm_sitl.bus.session import error_line, open_plain_router, router_runtime
    from swarm_sitl.nodes.leader import LEADER_POLL_S

    edges = cfg.graph_edges()
    ids = [f.id for f in cfg.followers]
    sample, setpoint, estimate = message_sizes()
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    router_at = f"tcp/127.0.0.1:{probe.getsockname()[1]}"
    probe.close()
    try:
        with router_runtime():
            router = open_plain_router([router_at])
    except zenoh.ZError as e:
        raise EmptySwarmError(f"empty swarm: no router at {router_at}: {error_line(e)}") from None
    procs: list[subprocess.Popen[str]] = []
    try:
        vehicles = [_spawn("vehicle", {"sample_bytes": sample}) for _ in ids]
        procs += vehicles
        ports = [int(_line(v, "vehicle").split()[1]) for v in vehicles]
        common = {"router": router_at, "ticks": ticks, "estimate_bytes": estimate}
        controllers = [
            _spawn(
                "controller",
                {
                    **common,
                    "id": i,
                    "ins": [s for s, d in edges if d == i],
                    "outs": [d for s, d in edges if s == i],
                    "vehicle_port": port,
                    "setpoint_bytes": setpoint,
                    "status_every": cfg.run.status_every,
                },
            )
            for i, port in zip(ids, ports, strict=True)
        ]
        procs += controllers
        leader = _spawn(
            "leader",
            {
                **common,
                "outs": [d for s, d in edges if s == 0],
                "followers": ids,
                "window": cfg.run.lockstep_window,
                "poll_s": LEADER_POLL_S,
            },
        )
        procs.append(leader)
        for p in [*controllers, leader]:
            _line(p, "node")
        time.sleep(1.0)  # every subscription known to the router before the first put
        cpu0, t0 = time.process_time(), time.monotonic()
        for p in procs:
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()
        done = [json.loads(_line(p, "controller")) for p in controllers]
        wall = time.monotonic() - t0
        router_cpu = time.process_time() - cpu0
        led = json.loads(_line(leader, "leader"))
        veh = [json.loads(_line(v, "vehicle")) for v in vehicles]
        for p in procs:
            p.wait(timeout=STALL_S)
    except subprocess.TimeoutExpired:
        raise EmptySwarmError("empty swarm: a process did not exit after its last tick") from None
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        router.close()
    return EmptyRun(
        len(ids),
        ticks,
        wall,
        {
            "vehicles": sum(v["cpu_s"] for v in veh),
            "controllers": sum(d["cpu_s"] for d in done),
            "leader": led["cpu_s"],
            "router": router_cpu,
        },
        {i: d["received"] for i, d in zip(ids, done, strict=True)},
        {i: v["answered"] for i, v in zip(ids, veh, strict=True)},
    )


def main(argv: list[str]) -> None:
    role, args = argv[0], json.loads(argv[1])
    batch_scheduling()
    try:
        if role == "vehicle":
            _vehicle(args["sample_bytes"])
        elif role == "controller":
            _controller(args["id"], args)
        else:
            _leader(args)
    except (OSError, zenoh.ZError) as e:  # a stall (socket timeout) or zenoh: one line, exit 1
        from swarm_sitl.bus.session import error_line

        raise SystemExit(f"empty swarm {role}: {type(e).__name__}: {error_line(e)}") from None


if __name__ == "__main__":
    main(sys.argv[1:])
