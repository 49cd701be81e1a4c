"""A controller's start-up with its vehicle, as an offboard companion computer does it with PX4:
the handshake layer of ``VehicleLink``.

``connect``: the autopilot's heartbeat, then its parameters (the controller flies with the mass
and maximum thrust the vehicle reports, never a copy of its own); ``request_rates``:
LOCAL_POSITION_NED and ATTITUDE_QUATERNION at the control rate and the streams it does not use at
a lower rate (MAV_CMD_SET_MESSAGE_INTERVAL: parsing MAVLink is the largest cost of a lockstep
tick); ``arm_offboard``: arm, then OFFBOARD the way PX4 takes it; in lockstep ``advance_to`` (a
restarted controller takes its vehicle up at its restart tick) and ``request_sample``. Each step
is retried until answered and ends in ``LinkError`` naming what did not come.
"""

import time
from collections.abc import Callable
from typing import Any, Protocol

from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import px4_profile as px4
from swarm_sitl.link.transport import LinkError

REQUIRED_PARAMS = ("MASS_KG", "MAX_THRUST_N")


class Link(Protocol):
    """What the handshake uses of a link (``vehicle_link.VehicleLink``)."""

    url: str
    system_id: int
    conn: Any  #: the pymavlink connection (``select``)
    params: dict[str, float]
    acks: dict[int, int]

    @property
    def heartbeat(self) -> Any: ...
    @property
    def sample_ms(self) -> int: ...
    def poll(self, readable: bool = False, until_ms: int = -1) -> int: ...
    def send_heartbeat_if_due(self) -> None: ...
    def send_clock_only(self, time_boot_ms: int) -> None: ...
    def command(self, command: int, *params: float) -> None: ...


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
            raise LinkError(f"{link.url}: no {what} within {timeout_s:g} s")
        if resend is not None and now >= next_send:
            resend()
            next_send = now + every_s
        link.send_heartbeat_if_due()
        link.conn.select(0.02)
        link.poll()


def connect(link: Link, timeout_s: float) -> None:
    """Heartbeat and parameters; raises ``LinkError`` naming what is missing."""
    wait(link, lambda: link.heartbeat is not None, f"HEARTBEAT from system {link.system_id}", timeout_s)
    wait(
        link,
        lambda: all(k in link.params for k in REQUIRED_PARAMS),
        f"parameters {', '.join(REQUIRED_PARAMS)}",
        timeout_s,
        lambda: link.conn.mav.param_request_list_send(link.system_id, px4.AUTOPILOT),
        1.0,
    )


def request_rates(link: Link, period_s: float, other_hz: float, timeout_s: float) -> None:
    """LOCAL_POSITION_NED and ATTITUDE_QUATERNION once per ``period_s``; ATTITUDE and
    HIGHRES_IMU, which the controller does not use, at ``other_hz`` (0: off)."""
    for msg_id in (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
        command_acked(link, mav.MAV_CMD_SET_MESSAGE_INTERVAL, timeout_s, float(msg_id), period_s * 1e6)
    other_us = 1e6 / other_hz if other_hz > 0 else -1.0
    for msg_id in (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAVLINK_MSG_ID_HIGHRES_IMU):
        command_acked(link, mav.MAV_CMD_SET_MESSAGE_INTERVAL, timeout_s, float(msg_id), other_us)


def arm_offboard(link: Link, timeout_s: float) -> None:
    """Arm, then OFFBOARD the way PX4 takes it: with a setpoint stream already running (a
    clock-only setpoint stamped with the vehicle's time, before each request: it holds what it
    holds and, in lockstep, moves no clock)."""
    command_acked(link, mav.MAV_CMD_COMPONENT_ARM_DISARM, timeout_s, 1.0)
    offboard = (float(px4.BASE_FLAGS), float(px4.MAIN_OFFBOARD), 0.0)
    command_acked(
        link,
        mav.MAV_CMD_DO_SET_MODE,
        timeout_s,
        *offboard,
        before=lambda: link.send_clock_only(max(link.sample_ms, 0)),
    )


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
    link: Link, command: int, timeout_s: float, *params: float, before: Callable[[], None] | None = None
) -> None:
    """Send ``command`` until it is answered (``before()`` ahead of each try); ``LinkError`` if
    it is refused or never answered. A temporary refusal is tried again, as MAVSDK does, until
    ``timeout_s``: on a lossy link the datagram ``before()`` sent (the setpoint that OFFBOARD
    needs) can be lost while the command gets through."""
    name = mav.enums["MAV_CMD"][command].name
    acks = link.acks
    acks.pop(command, None)  # an answer to an earlier command of the same kind is not ours

    def send() -> None:
        if before is not None:
            before()
        link.command(command, *params)

    def answered() -> bool:
        if acks.get(command) == mav.MAV_RESULT_TEMPORARILY_REJECTED and time.monotonic() < end:
            del acks[command]  # try again at the next resend
        return command in acks

    end = time.monotonic() + timeout_s
    wait(link, answered, f"COMMAND_ACK for {name}", timeout_s, send)
    if acks[command] != mav.MAV_RESULT_ACCEPTED:
        raise LinkError(f"{link.url}: {name} refused (MAV_RESULT {acks[command]})")
