"""A controller's MAVLink link to its vehicle, through any pymavlink connection string.

It is what an offboard companion computer is to PX4 or to an ArduCopter (``dialects``: which one
its HEARTBEAT says), in layers: the datagrams each way with
their signing, fault plan and arrival stamps (``transport``), what is read from them: the sample,
heartbeat, parameters and acks (``decoding``), what is sent: setpoints, heartbeat, commands
(``setpoints``), and the start-up sequence (``handshake``). NED/FRD exists only in
``sim_vehicles.mavlink``.

Incoming messages are read with ``poll()`` (non-blocking; ``fileno()`` is there for ``select``).
The latest vehicle sample is the last LOCAL_POSITION_NED and ATTITUDE_QUATERNION of the same
``time_boot_ms``; ``sample_arrival_mono`` is when it arrived (``time.monotonic`` seconds): the
kernel's receive stamp on a ``udpout:`` link where it has them (``stamps_arrivals``), else when
``poll()`` read it.
"""

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink.thrust_map import boost_compensated, full_thrust_N
from swarm_sitl.link import handshake
from swarm_sitl.link.decoding import Downlink
from swarm_sitl.link.dialects import ARDUPILOT, Dialect
from swarm_sitl.link.setpoints import Setpoints
from swarm_sitl.link.transport import LinkError, Transport


class VehicleLink:
    """Controller ``system_id``'s link to its vehicle at ``url``; ``transport``: the keywords of
    ``transport.Transport`` (``stamp_arrivals``, ``faults``, ``signing_key``: it says what each
    does)."""

    def __init__(self, url: str, system_id: int, **transport: Any):
        self.url = url
        self.system_id = system_id
        self.transport = Transport(url, system_id, **transport)
        self.conn = self.transport.conn
        self.downlink = Downlink(system_id, self.conn.mav, self.transport.whole_datagrams)
        self.setpoints = Setpoints(self.transport, system_id)
        self.params = self.downlink.params  #: the vehicle's parameters, as it reported them
        self.acks = self.downlink.acks  #: the latest COMMAND_ACK's result by command
        self.dialect: Dialect | None = None  #: its autopilot's (``connect``)
        #: the thrust a field of 1.0 means, ``m g / hover`` (``thrust_map``; ``connect``) [N]
        self.full_thrust_N = math.nan
        self.mass_kg = math.nan  #: the vehicle's, from the config (no autopilot has it) [kg]
        self.g_mps2 = math.nan
        #: an ArduCopter's angle boost is on: the thrust asked for is the commanded tilt's share
        self.angle_boost = False
        #: ``() -> (time_boot_s, p_W, v_W, q_WB)``: the latest complete sample, in ENU/FLU (the
        #: downlink's own method: one call a tick, not two)
        self.sample: Callable[[], tuple[float, np.ndarray, np.ndarray, np.ndarray]] = self.downlink.sample
        #: ``time_boot_ms`` of the latest complete sample (-1: none yet), and when it arrived [s;
        #: ``time.monotonic``]: the downlink's, as of the last ``poll`` (plain attributes: the
        #: controller reads them several times a tick)
        self.sample_ms = -1
        self.sample_arrival_mono = math.nan

    # -- receive ---------------------------------------------------------------------------------
    def poll(self, readable: bool = False, until_ms: int = -1) -> int:
        """Read everything waiting; returns the number of messages handled. ``readable``: a
        ``select`` on ``fileno()`` has just said so (the first read needs no check). ``until_ms``:
        stop once the sample of that instant has come (lockstep: what else waits is read at the
        next tick, whose wait finds the socket readable), saving a look at an empty socket."""
        n = 0
        downlink = self.downlink
        read = downlink.read
        for data, arrival in self.transport.datagrams(readable):
            got, sample_ms = read(data, arrival)
            n += got
            if sample_ms >= 0 and sample_ms == until_ms:
                break
        self.sample_ms, self.sample_arrival_mono = downlink.sample_ms, downlink.sample_arrival_mono
        return n

    @property
    def heartbeat(self) -> Any:
        """The autopilot's latest HEARTBEAT (None until one came)."""
        return self.downlink.heartbeat

    @property
    def statustext(self) -> str:
        """The autopilot's latest STATUSTEXT ("": none yet)."""
        return self.downlink.statustext

    def check_vehicle(self) -> None:
        """``LinkError`` (one line) if the vehicle is no longer the one engaged: it rebooted, or
        disarmed (``decoding.Downlink.gone``). A controller asks at every tick."""
        if self.downlink.gone:
            raise LinkError(
                f"follower {self.system_id}: {self.url}: mid-run, {self.downlink.gone}{handshake.said(self)}"
            )

    def sample_settled(self, time_boot_ms: int) -> bool:
        """Lockstep: whether the sample of ``time_boot_ms`` has come, or a fault plan lost it."""
        if self.downlink.sample_ms == time_boot_ms:
            return True
        faults = self.transport.faults
        return faults is not None and faults.lost_ms == time_boot_ms

    @property
    def rx_bad(self) -> int:
        """What was dropped: bad signatures, bad CRCs, frames that do not decode, garbage."""
        return self.transport.rx_bad + self.downlink.rx_bad

    @property
    def rx_refused(self) -> int:
        """Unsigned or replayed datagrams on a signed link."""
        return self.transport.rx_refused

    @property
    def stamps_arrivals(self) -> bool:
        return self.transport.stamps_arrivals

    def fileno(self) -> int:
        return self.transport.fileno()

    def block_reads(self, timeout_s: float) -> None:
        self.transport.block_reads(timeout_s)

    def close(self) -> None:
        self.transport.close()

    # -- send ------------------------------------------------------------------------------------
    def send_setpoint(self, cmd: AttitudeCommand, time_boot_ms: int) -> None:
        """``cmd`` as SET_ATTITUDE_TARGET, its thrust as the autopilot reads it (``thrust_map``:
        a fraction of ``full_thrust_N``, on an ArduCopter with angle boost the commanded tilt's
        share of it)."""
        if self.angle_boost:
            cmd = cmd._replace(thrust_N=boost_compensated(float(cmd.thrust_N), cmd.q_c))
        self.setpoints.send(cmd, time_boot_ms, self.full_thrust_N)

    def send_neutral(self) -> None:
        """A setpoint of the vehicle's attitude now (level before a sample came) at hover
        thrust, stamped with its time: what PX4 counts as the setpoint stream OFFBOARD needs,
        and holds it as it is if taken."""
        q = self.sample()[3] if self.sample_ms >= 0 else np.array([1.0, 0.0, 0.0, 0.0])
        hover = AttitudeCommand(q_c=np.array(q, dtype=float), thrust_N=self.mass_kg * self.g_mps2)
        self.send_setpoint(hover, max(self.sample_ms, 0))

    def send_clock_only(self, time_boot_ms: int) -> None:
        self.setpoints.clock_only(time_boot_ms)

    def send_heartbeat_if_due(self) -> None:
        self.setpoints.heartbeat_if_due()

    def command(self, command: int, *params: float) -> None:
        self.setpoints.command(command, *params)

    # -- the start-up handshake (``handshake``) ---------------------------------------------------
    def connect(self, timeout_s: float, mass_kg: float, g_mps2: float) -> Dialect:
        """The handshake's ``connect``, then the thrust map of a vehicle of ``mass_kg``: the
        hover thrust it reports is ``m g`` (``thrust_map.full_thrust_N``)."""
        dialect = handshake.connect(self, timeout_s)
        self.mass_kg, self.g_mps2 = mass_kg, g_mps2
        self.full_thrust_N = full_thrust_N(mass_kg, g_mps2, self.params[dialect.hover_param])
        self.angle_boost = dialect is ARDUPILOT and round(self.params["ATC_ANGLE_BOOST"]) != 0
        return dialect

    def request_rates(self, period_s: float, other_hz: float, timeout_s: float) -> None:
        handshake.request_rates(self, period_s, other_hz, timeout_s)

    def engage(self, timeout_s: float, lockstep: bool) -> None:
        handshake.engage(self, timeout_s, lockstep)

    def advance_to(self, time_boot_ms: int, timeout_s: float) -> None:
        handshake.advance_to(self, time_boot_ms, timeout_s)

    def request_sample(self, timeout_s: float) -> None:
        handshake.request_sample(self, timeout_s)
