"""A controller's start-up with its vehicle, as an offboard companion computer does it with PX4 or
with an ArduCopter: the handshake layer of ``VehicleLink``.

``connect``: the autopilot's heartbeat (which says who it is: ``dialects``), then the parameters
its dialect reads, by name (PARAM_REQUEST_READ), and on an ArduCopter ``GUID_OPTIONS`` bit 3 set
and read back; ``request_rates``: LOCAL_POSITION_NED and ATTITUDE_QUATERNION at the control rate
and the streams it does not use at a lower rate (MAV_CMD_SET_MESSAGE_INTERVAL: parsing MAVLink is
the largest cost of a lockstep tick); ``engage``: arm and OFFBOARD the way PX4 takes them, or
GUIDED_NOGPS and arm the way ArduCopter does; in lockstep ``advance_to`` (a restarted controller
takes its vehicle up at its restart tick) and ``request_sample``.

Each step is retried until answered and ends in ``LinkError``, one line naming the follower, the
step and the autopilot's own answer (its COMMAND_ACK result, the last STATUSTEXT it sent), never
a hang: every wait ends at its timeout.
"""

import time
from collections.abc import Callable
from typing import Any, Protocol

from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import ardupilot_profile as ap
from swarm_sitl.link.dialects import ARDUPILOT, Dialect, autopilot_name, dialect_of
from swarm_sitl.link.transport import LinkError


class Link(Protocol):
    """What the handshake uses of a link (``vehicle_link.VehicleLink``)."""

    url: str
    system_id: int
    conn: Any  #: the pymavlink connection (``select``)
    params: dict[str, float]
    acks: dict[int, int]
    dialect: Dialect | None

    @property
    def heartbeat(self) -> Any: ...
    @property
    def statustext(self) -> str: ...
    @property
    def sample_ms(self) -> int: ...
    def poll(self, readable: bool = False, until_ms: int = -1) -> int: ...
    def send_heartbeat_if_due(self) -> None: ...
    def send_clock_only(self, time_boot_ms: int) -> None: ...
    def send_neutral(self) -> None: ...
    def command(self, command: int, *params: float) -> None: ...


def _who(link: Link) -> str:
    return f"follower {link.system_id}"


def said(link: Link) -> str:
    """The autopilot's last STATUSTEXT, as a tail for a line ("": none came)."""
    return f"; its last STATUSTEXT: {link.statustext!r}" if link.statustext else ""


def wait(
    link: Link,
    done: Callable[[], bool],
    what: str,
    timeout_s: float,
    resend: Callable[[], None] | None = None,
    every_s: float = 0.5,
) -> None:
    """Read the link until ``done()``, ``resend()`` every ``every_s`` and the heartbeat when due;
    ``LinkError`` after ``timeout_s`` naming ``what`` did not come."""
    end = time.monotonic() + timeout_s
    next_send = 0.0
    while not done():
        now = time.monotonic()
        if now > end:
            raise LinkError(f"{_who(link)}: {link.url}: no {what} within {timeout_s:g} s{said(link)}")
        if resend is not None and now >= next_send:
            resend()
            next_send = now + every_s
        link.send_heartbeat_if_due()
        link.conn.select(0.02)
        link.poll()


def connect(link: Link, timeout_s: float) -> Dialect:
    """Heartbeat, then the dialect's parameters (an ArduCopter's ``GUID_OPTIONS`` bit 3 set if
    it is clear); its dialect. ``LinkError`` naming what is missing or refused."""
    wait(link, lambda: link.heartbeat is not None, f"HEARTBEAT from system {link.system_id}", timeout_s)
    dialect = dialect_of(link.heartbeat)
    if dialect is None:
        raise LinkError(
            f"{_who(link)}: {link.url}: its HEARTBEAT says {autopilot_name(link.heartbeat.autopilot)}, "
            "neither PX4 nor ArduPilot"
        )
    link.dialect = dialect
    for name in dialect.read:
        read_param(link, name, timeout_s)
    if dialect is ARDUPILOT:
        options = round(link.params["GUID_OPTIONS"])
        if not options & ap.THRUST_AS_THRUST:
            set_param(
                link, "GUID_OPTIONS", options | ap.THRUST_AS_THRUST, mav.MAV_PARAM_TYPE_INT32, timeout_s
            )
    return dialect


def _param_value(link: Link, name: str, what: str, timeout_s: float, ask: Callable[[], None]) -> float:
    """``ask()`` until a PARAM_VALUE of ``name`` comes (one that came before does not count)."""
    link.params.pop(name, None)
    wait(link, lambda: name in link.params, what, timeout_s, ask)
    return link.params[name]


def read_param(link: Link, name: str, timeout_s: float) -> float:
    """The autopilot's value of parameter ``name`` (PARAM_REQUEST_READ by name, asked again until
    its PARAM_VALUE comes)."""
    return _param_value(
        link,
        name,
        f"PARAM_VALUE for {name} (the autopilot does not have it, or does not answer)",
        timeout_s,
        lambda: link.conn.mav.param_request_read_send(link.system_id, 1, name.encode(), -1),
    )


def set_param(link: Link, name: str, value: float, kind: int, timeout_s: float) -> None:
    """PARAM_SET, until its PARAM_VALUE says ``value``; ``LinkError`` if it keeps another."""
    kept = _param_value(
        link,
        name,
        f"PARAM_VALUE for {name} after PARAM_SET",
        timeout_s,
        lambda: link.conn.mav.param_set_send(link.system_id, 1, name.encode(), float(value), kind),
    )
    if kept != float(value):
        raise LinkError(
            f"{_who(link)}: {link.url}: PARAM_SET {name} {value:g} refused: it keeps {kept:g}{said(link)}"
        )


def request_rates(link: Link, period_s: float, other_hz: float, timeout_s: float) -> None:
    """LOCAL_POSITION_NED and ATTITUDE_QUATERNION once per ``period_s``; ATTITUDE and
    HIGHRES_IMU, which the controller does not use, at ``other_hz`` (0: off)."""
    for msg_id in (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
        command_acked(link, mav.MAV_CMD_SET_MESSAGE_INTERVAL, timeout_s, float(msg_id), period_s * 1e6)
    other_us = 1e6 / other_hz if other_hz > 0 else -1.0
    for msg_id in (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAVLINK_MSG_ID_HIGHRES_IMU):
        command_acked(link, mav.MAV_CMD_SET_MESSAGE_INTERVAL, timeout_s, float(msg_id), other_us)


def engage(link: Link, timeout_s: float, lockstep: bool) -> None:
    """Arm and hand the vehicle to its controller as its autopilot takes it (``dialects``): PX4
    armed, then OFFBOARD with a setpoint stream already running (before each try: in lockstep a
    clock-only setpoint stamped with the vehicle's time, which holds what it holds and moves no
    clock; in real time a setpoint of its attitude now at hover thrust, which PX4 counts as the
    stream); an ArduCopter in GUIDED_NOGPS, then armed."""
    d = link.dialect
    assert d is not None  # (connected)

    def stream() -> None:
        if lockstep:
            link.send_clock_only(max(link.sample_ms, 0))
        else:
            link.send_neutral()

    def arm() -> None:
        command_acked(link, mav.MAV_CMD_COMPONENT_ARM_DISARM, timeout_s, 1.0, step="arming")

    if d.arm_first:
        arm()
    before = stream if d.stream_before_mode else None
    command_acked(link, mav.MAV_CMD_DO_SET_MODE, timeout_s, *d.mode, before=before, step=d.mode_name)
    if not d.arm_first:
        arm()


def advance_to(link: Link, time_boot_ms: int, timeout_s: float) -> None:
    """Lockstep: move the vehicle's clock to ``time_boot_ms`` without a new setpoint (a
    clock-only SET_ATTITUDE_TARGET, every field ignored: it flies what it holds, its failsafe
    once its setpoints are overdue) and wait for its sample there."""
    wait(
        link,
        lambda: link.sample_ms >= time_boot_ms,
        f"the vehicle's clock at {time_boot_ms} ms",
        timeout_s,
        lambda: link.send_clock_only(time_boot_ms),
    )


def request_sample(link: Link, timeout_s: float) -> None:
    """Ask for LOCAL_POSITION_NED and ATTITUDE_QUATERNION now (MAV_CMD_REQUEST_MESSAGE)."""

    def ask() -> None:
        for msg_id in (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
            link.command(mav.MAV_CMD_REQUEST_MESSAGE, float(msg_id))

    wait(link, lambda: link.sample_ms >= 0, "LOCAL_POSITION_NED and ATTITUDE_QUATERNION", timeout_s, ask)


def command_acked(
    link: Link,
    command: int,
    timeout_s: float,
    *params: float,
    before: Callable[[], None] | None = None,
    step: str = "",
) -> None:
    """Send ``command`` until it is answered (``before()`` ahead of each try); ``LinkError`` if
    it is refused or never answered, naming ``step`` (default: the command) and the answer. A
    temporary refusal is tried again, as MAVSDK does, until ``timeout_s``: on a lossy link the
    datagram ``before()`` sent (the setpoint that OFFBOARD needs) can be lost while the command
    gets through."""
    name = mav.enums["MAV_CMD"][command].name
    acks = link.acks
    acks.pop(command, None)  # an answer to an earlier command of the same kind is not ours
    last = [-1]

    def send() -> None:
        if before is not None:
            before()
        link.command(command, *params)

    def answered() -> bool:
        if acks.get(command) == mav.MAV_RESULT_TEMPORARILY_REJECTED and time.monotonic() < end:
            last[0] = acks.pop(command)  # try again at the next resend
        return command in acks

    end = time.monotonic() + timeout_s
    what = f"COMMAND_ACK for {name}" + (f" ({step})" if step else "")
    try:
        wait(link, answered, what, timeout_s, send)
    except LinkError:
        if last[0] < 0:
            raise
        result = mav.enums["MAV_RESULT"][last[0]].name
        raise LinkError(
            f"{_who(link)}: {link.url}: {step or name} refused: {name} answered {result} for "
            f"{timeout_s:g} s{said(link)}"
        ) from None
    if acks[command] != mav.MAV_RESULT_ACCEPTED:
        result = mav.enums["MAV_RESULT"][acks[command]].name
        raise LinkError(
            f"{_who(link)}: {link.url}: {step or name} refused: {name} answered {result}{said(link)}"
        )
