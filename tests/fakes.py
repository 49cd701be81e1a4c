"""In-process fakes of the bench's interfaces, shared by the tests that drive a piece without its
processes: an in-memory node bus (``MemoryBus``) and a publisher's (``Publisher``), a real-time
clock the test sets (``ManualClock``), the leader's bus with no one on it (``LeaderBus``) with
the short config a leader's tests fly (``leader_config``), where a pymavlink link writes what it
sends (``FrameSink``), a socket that keeps what a vehicle driven in process sends
(``RecordingSocket``), and such a vehicle (``recording_endpoint``) with what it answers a message
(``answers``)."""

import time
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.state import make_state
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from swarm_sitl.bus.clock import WallTime
from swarm_sitl.bus.codec import HOLD_NONE, Message
from swarm_sitl.bus.node_bus import ZenohNodeBus

DT = 0.01  #: the paper's control period [s]: the fakes' tick
EDGES = [(0, 1), (0, 2), (1, 4), (2, 4)]  #: a small graph: the leader to 1 and 2, both to 4


class MemoryBus:
    """The part of ``ZenohNodeBus`` a fault stage uses, in memory: ``arrive`` puts an estimate on
    the wire, ``poll`` decodes what arrived through ``deliver``."""

    def __init__(self) -> None:
        self.deliver = self.file
        self.dropped = 0
        self.wire: list[Message] = []
        self.table: dict[tuple[int, int], Message] = {}
        self.newest: dict[int, Message] = {}
        self.counted_steps: range | None = None

    counts = ZenohNodeBus.counts

    def arrive(self, src: int, step: int) -> None:
        self.wire.append(Message(src, step, step * DT, np.full(12, float(step))))

    def poll(self) -> None:
        while self.wire:
            self.deliver(self.wire.pop(0))

    def file(self, m: Message) -> None:
        self.table[m.src, m.step] = m
        if m.src not in self.newest or m.step >= self.newest[m.src].step:
            self.newest[m.src] = m

    def estimate(self, src: int, step: int) -> Message | None:
        return self.table.get((src, step))

    def latest(self, src: int) -> Message | None:
        return self.newest.get(src)


class ManualClock(WallTime):
    """A real-time run's clock that reads ``self.t`` [s], set by the test."""

    def __init__(self) -> None:
        super().__init__(False, DT)
        self.t = 0.0
        self.epoch_mono = 0.0  # started: it reads ``t``

    def now(self) -> float:
        return self.t

    def now_s(self) -> float:
        return self.t


class Publisher(MemoryBus):
    """A node's inner bus as a publisher sees it: what it sent, the progress its out-neighbours
    reported (none here: their statuses were sent before this session existed) and their
    liveliness tokens."""

    def __init__(self, alive: dict[int, int]):
        super().__init__()
        self.sent: list[int] = []
        self.alive = alive

    def publish(self, m: Message) -> None:
        self.sent.append(m.step)

    def progress(self, follower: int) -> int:
        return -1

    def alive_puts(self, node: int) -> int:
        return self.alive.get(node, 0)


class LeaderBus:
    """A bus with no one on it but what the test says: the followers' progress, the start."""

    def __init__(self, progress: int = -1):
        self.published: list[int] = []
        self.at = progress
        self.dropped = 0

    def set_ready(self) -> None: ...
    def fileno(self) -> int:
        return -1

    def poll(self) -> None: ...
    def hold_tick(self) -> int:
        return HOLD_NONE

    def start_epoch(self) -> float:
        return time.time()

    def progress(self, follower: int) -> int:
        return self.at

    def publish(self, msg) -> None:
        self.published.append(msg.step)

    def drain(self, timeout_s: float) -> bool:
        return True


def leader_config():
    """The paper's config, 8 s long, with a stall timeout of 0.3 s: what a leader driven over a
    ``LeaderBus`` flies (800 ticks)."""
    from tests.support import config

    cfg = config("paper").model_copy(update={"duration_s": 8.0})
    return cfg.model_copy(update={"run": cfg.run.model_copy(update={"stall_timeout_s": 0.3})})


class FrameSink:
    """Where a pymavlink ``MAVLink`` object writes what it sends (its ``file``): keeps every frame."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data))


class RecordingSocket:
    """In place of a vehicle port's UDP socket (``port.sock``): keeps every datagram sent."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def sendto(self, data: bytes, addr: object) -> int:
        self.sent.append(bytes(data))
        return len(data)

    def close(self) -> None:
        pass


#: the vehicle the endpoint tests drive: 0.85 kg, its inertia, 25 N at most
ENDPOINT_PARAMS = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0)


def recording_endpoint(system_id: int = 3, autopilot: Any = None, **endpoint: Any) -> VehicleEndpoint:
    """A vehicle endpoint driven in process (``VehicleEndpoint`` with ``endpoint``'s fields), its
    ``autopilot`` (by default the plain one hovering at 10 m), its datagrams kept by a
    ``RecordingSocket`` on each of its ports (``answers``)."""
    if autopilot is None:
        autopilot = Autopilot(ENDPOINT_PARAMS, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 10.0]), 0.001)
    ep = VehicleEndpoint(autopilot, system_id, **endpoint)
    for port in (ep.port, ep.gcs):  # (the ground station's too, where it has one)
        if port is not None:
            port.sock.close()
            port.sock = RecordingSocket()
    return ep


def answers(
    ep: VehicleEndpoint, msg: Any, sysid: int, compid: int, peer: tuple[str, int] = ("127.0.0.1", 40001)
) -> list:
    """What ``recording_endpoint`` ``ep`` sends back for ``msg`` from (``sysid``, ``compid``) at
    ``peer``, heartbeats aside."""
    link = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    ep.port.sock.sent.clear()
    ep.datagram(bytes(msg.pack(link)), peer)
    ep.port.flush()
    back = mav.MAVLink(None)
    out = [m for data in ep.port.sock.sent for m in back.parse_buffer(data) or []]
    return [m for m in out if m.get_type() != "HEARTBEAT"]
