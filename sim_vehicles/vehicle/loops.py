"""The two run loops of a vehicle (``endpoint.VehicleEndpoint``): real time and lockstep.

- ``run_realtime``: the vehicle steps with the wall clock (``time.monotonic``). The plant is
  caught up to each datagram's arrival before the datagram is handled, so a setpoint takes effect
  at the attitude step in which it arrived. While setpoints stream in (offboard) and the kernel
  stamps arrivals (``udp_arrival``), the loop wakes only when a telemetry message or the failsafe
  is due, or ``RX_EVERY_S`` after its last read, and reads what came in between: one wake-up per
  period instead of two. Otherwise it also wakes for each datagram.
- ``run_lockstep``: simulated time moves only with the setpoints (the endpoint's doc). One
  datagram per wake-up, read by a blocking ``recvfrom`` that gives up after ``LOCKSTEP_WAIT_S``
  (``SO_RCVTIMEO``) so the heartbeat and ``stop()`` still get their turn: one system call where a
  ``select`` and a drain would take three.

The heartbeat runs on the wall clock in both, and the ground station's port is looked at between
the controller's datagrams.
"""

import select
import time
from collections.abc import Callable
from typing import Any, Protocol

from sim_vehicles.plant.contract import VehicleModel
from sim_vehicles.runtime import udp_arrival
from sim_vehicles.vehicle.modes import FlightModes
from sim_vehicles.vehicle.port import Port

RX_EVERY_S = 0.01  #: real time, offboard: longest a datagram waits to be read [s]
LOCKSTEP_WAIT_S = 0.2  #: lockstep: longest wait for a datagram before the heartbeat is checked [s]
#: lockstep: how often the ground-station port is looked at between setpoints [s of wall clock]
#: (every setpoint, a system call per tick that nearly always finds nothing)
LOCKSTEP_GCS_EVERY_S = 0.005


class Served(Protocol):
    """What a loop drives: the vehicle (``endpoint.VehicleEndpoint``)."""

    autopilot: VehicleModel
    boot_unix_s: float  #: real time: the UNIX instant of time_boot_ms = 0
    port: Port
    gcs: Port | None
    flight: FlightModes

    @property
    def offboard(self) -> bool: ...
    def poll(self, at_arrival: Callable[[float], None] | None = None, readable: bool = False) -> None: ...
    def poll_gcs(self) -> None: ...
    def step(self, n_steps: int = 1) -> None: ...
    def heartbeat_tick(self, now_wall_s: float) -> None: ...
    def datagram(self, data: bytes, addr: Any, port: Port | None = None) -> None: ...


def run_realtime(v: Served, duration_s: float | None = None, stop: Callable[[], bool] | None = None) -> None:
    """Step ``v`` with the wall clock until ``duration_s`` of wall time or ``stop()``."""
    start = time.monotonic()
    ap = v.autopilot
    dt = ap.dt_s
    k0 = ap.step_index
    v.boot_unix_s = time.time() - k0 * dt
    port = v.port
    socks = [port.sock] + ([] if v.gcs is None else [v.gcs.sock])

    def catch_up(mono_s: float) -> None:
        due = k0 + int((mono_s - start) / dt) - ap.step_index
        if due > 0:
            v.step(due)

    while True:
        deferred = port.stamped and v.offboard
        if deferred:
            v.poll(catch_up)
            v.poll_gcs()
        now = time.monotonic() - start
        if (duration_s is not None and now >= duration_s) or (stop is not None and stop()):
            return
        t_next = port.streams.next_any_s - k0 * dt
        if v.offboard:
            t_next = min(t_next, v.flight.last_setpoint_s + v.flight.setpoint_timeout_s - k0 * dt)
        due = k0 + int(now / dt) - ap.step_index
        if due > 0 and now >= t_next:  # only a stream or the failsafe needs the state now
            v.step(due)
            continue
        v.heartbeat_tick(start + now)
        wait = min(max(t_next - now, 0.0), 0.05)
        if deferred:
            time.sleep(min(wait, RX_EVERY_S))
        elif port.sock in select.select(socks, [], [], wait)[0]:
            v.poll(catch_up, readable=True)
        v.poll_gcs()


def run_lockstep(v: Served, stop: Callable[[], bool] | None = None) -> None:
    """Serve ``v``'s setpoints until ``stop()``: simulated time moves only with them."""
    sock = v.port.sock
    udp_arrival.block_reads(sock, LOCKSTEP_WAIT_S)
    try:
        next_gcs = 0.0
        while stop is None or not stop():
            now = time.monotonic()
            v.heartbeat_tick(now)
            if now >= next_gcs:  # a ground station waits LOCKSTEP_WAIT_S at most, or 5 ms and a tick
                next_gcs = now + LOCKSTEP_GCS_EVERY_S
                v.poll_gcs()
            try:
                data, addr = sock.recvfrom(4096)
            except OSError:  # the wait ran out (EAGAIN), or an ICMP error
                continue
            try:
                v.datagram(data, addr)
            finally:
                v.port.flush()
    finally:
        udp_arrival.block_reads(sock, 0.0)
