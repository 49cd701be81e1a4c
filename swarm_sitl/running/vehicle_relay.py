"""A fault plan's MAVLink faults at a vehicle's own port, for a controller the bench does not run
(``swarm-sitl vehicles CONFIG --faults FILE``).

Each vehicle with ``mavlink: i`` entries in the plan gets a relay: the port its controller is told
(``--base-port``'s, or a free one) is the relay's; the vehicle itself listens on a free loopback
port behind it. Every datagram from the controller (uplink: setpoints, commands) and from the
vehicle (downlink: telemetry, answers) meets its fate under the plan (``faults.mavlink``, as in
``run``: loss, drop, corrupt, delay with jitter, stall, duplicate, each way apart), in real time,
the plan's windows in seconds since the vehicles came up. Whoever speaks to the relay's port is
the controller it answers (as a vehicle answers its peer). Signing passes through untouched: a
corrupted frame fails its CRC (or its signature) at the receiver, which drops and counts it.
"""

import math
import select
import socket
import threading
import time
from typing import Any

from swarm_sitl.bus.clock import RunClock
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.mavlink import MavlinkFaults

#: how long the relay thread sleeps at most when nothing is held (it wakes on any datagram)
IDLE_S = 0.05


class VehicleRelay:
    """Vehicle ``vehicle``'s controller port, ``public`` (host, port), in front of its real one."""

    def __init__(
        self, vehicle: int, public: tuple[str, int], vehicle_addr: tuple[str, int], faults: MavlinkFaults
    ):
        self.vehicle = vehicle
        self.faults = faults
        self.outer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.outer.bind(public)
        self.outer.setblocking(False)
        self.inner = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.inner.bind(("127.0.0.1", 0))
        self.inner.setblocking(False)
        self.vehicle_addr = vehicle_addr
        self.controller: Any = None  #: the address the controller last spoke from

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.outer.getsockname()[:2]
        return host, port

    def _to_vehicle(self, data: bytes) -> None:
        self.inner.sendto(data, self.vehicle_addr)

    def _to_controller(self, data: bytes) -> None:
        if self.controller is not None:
            self.outer.sendto(data, self.controller)

    def pump(self) -> None:
        """Pass on what waits each way, and what the plan held that is now due."""
        while True:
            try:
                data, addr = self.outer.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # an ICMP error of an earlier send: nothing to relay
                continue
            self.controller = addr
            self.faults.send(data, 0, self._to_vehicle, lambda _ms: None)
        while True:
            try:
                data = self.inner.recv(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                continue
            out = self.faults.receive(data)
            if out is not None:
                self._to_controller(out)
        for data in self.faults.release(self._to_vehicle):
            self._to_controller(data)

    def close(self) -> None:
        self.outer.close()
        self.inner.close()


class RelayThread:
    """The relays of a ``vehicles`` process, pumped by one thread until ``close``."""

    def __init__(self, relays: list[VehicleRelay], clock: RunClock):
        self.relays = relays
        self.clock = clock
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mavlink-relays", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        socks = [s for r in self.relays for s in (r.outer, r.inner)]
        while not self._stop.is_set():
            due = [d for r in self.relays if (d := r.faults.next_due_s()) is not None]
            wait = IDLE_S if not due else max(0.0, min(IDLE_S, min(due) - self.clock.now_s()))
            select.select(socks, [], [], wait)
            for r in self.relays:
                r.pump()

    def close(self) -> dict[str, dict[str, Any]]:
        """Stop, close, and return each link's counts (``mavlink <i> up|down``)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        out = {}
        for r in self.relays:
            for way, st in r.faults.link_stats().items():
                out[f"mavlink {r.vehicle} {way}"] = st
            r.close()
        return out


def start_relays(
    cfg: SwarmConfig, endpoints: dict[int, str], base_port: int, host: str, vehicles: frozenset[int]
) -> RelayThread:
    """A relay for each vehicle in ``vehicles`` (already listening at ``endpoints``), on the port
    ``base_port`` gives it (or a free one) on ``host``, under ``cfg``'s fault plan, from now."""
    clock = RunClock(False, cfg.control_dt_s)
    clock.epoch_mono = time.monotonic()
    relays = []
    for i in sorted(vehicles):
        vhost, vport = endpoints[i].removeprefix("udp:").rsplit(":", 1)
        faults = MavlinkFaults(cfg.faults, i, clock, math.inf)
        relays.append(VehicleRelay(i, (host, base_port + i if base_port else 0), (vhost, int(vport)), faults))
    thread = RelayThread(relays, clock)
    thread.start()
    return thread
