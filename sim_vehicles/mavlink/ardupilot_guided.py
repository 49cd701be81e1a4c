"""ArduCopter's reading of SET_ATTITUDE_TARGET in its guided modes, pure: fields in, the command it
flies out (``guided_command``). The vehicle endpoint and ``sim`` (``swarm_sitl.nodes.assembly.
Uplink``) call the same function, so a lockstep run of ArduCopter vehicles equals ``sim`` bit for
bit.

As ``GCS_MAVLINK_Copter::handle_message_set_attitude_target`` and ``ModeGuided`` do it: the
checks of ``ardupilot_profile.check_setpoint`` first (a refusal leaves the command it holds); then
the attitude (ignored: the one it holds, rates only), the body rates (all or none), and the thrust
field, which is either thrust (bit 3 of ``GUID_OPTIONS``): clamped to -1..1, boosted by the
vehicle's tilt now when ``ATC_ANGLE_BOOST`` is on, through the motors' thrust curve
(``ardupilot_profile.motor_thrust``) to a fraction of the vehicle's largest thrust; or a climb
rate (``ardupilot_profile.climb_rate_of``), which its own altitude loop holds
(``modes.FlightModes.climb_mps``). A non-finite field is refused as the PX4 profile refuses it.
"""

import math

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import QUAT
from sim_vehicles.mavlink.ardupilot_profile import (
    ArduCopterState,
    check_setpoint,
    climb_rate_of,
    motor_thrust,
)
from sim_vehicles.mavlink.thrust_map import boosted_throttle, cos_tilt
from sim_vehicles.mavlink.wire_format import (
    CMD_OMEGA,
    CMD_Q,
    IGNORE_ATTITUDE,
    IGNORE_RATES,
    AttitudeTargetFields,
    command_from_fields,
)


def guided_command(
    fields: AttitudeTargetFields,
    type_mask: int,
    held: AttitudeCommand,
    state: np.ndarray,
    max_thrust_N: float,
    kept: ArduCopterState,
) -> tuple[AttitudeCommand | None, float | None, str]:
    """``(command, climb rate [m/s] or None, "")`` ArduCopter flies for a SET_ATTITUDE_TARGET of
    ``fields`` (NED/FRD as on the wire) and ``type_mask``, holding ``held``, in ``state``, its
    rotors giving ``max_thrust_N`` at full thrust; or ``(None, None, why)`` where it does not
    take it."""
    refusal = check_setpoint(type_mask, fields.q)
    if refusal is not None:
        return None, None, refusal.why
    if not all(math.isfinite(v) for v in (*fields.body_rates, fields.thrust)):
        return None, None, "a value not finite"
    # (the frames converted as every setpoint's are; thrust is read below, not here)
    f = np.array([*fields.q, *fields.body_rates, 0.5], dtype=np.float64)
    decoded = command_from_fields(f, 1.0)
    q_c = held.q_c if type_mask & IGNORE_ATTITUDE else decoded[CMD_Q].copy()
    omega = np.zeros(3) if type_mask & IGNORE_RATES == IGNORE_RATES else decoded[CMD_OMEGA].copy()
    if not kept.thrust_as_thrust:
        climb = climb_rate_of(fields.thrust, kept.get("WPNAV_SPEED_UP"), kept.get("WPNAV_SPEED_DN"))
        return AttitudeCommand(q_c=q_c, thrust_N=float(held.thrust_N), omega_c_B=omega), climb, ""
    throttle = min(max(fields.thrust, -1.0), 1.0)
    if kept.angle_boost:
        throttle = boosted_throttle(throttle, cos_tilt(state[QUAT].tolist()))
    thrust_N = motor_thrust(throttle, kept.get("MOT_THST_EXPO")) * max_thrust_N
    return AttitudeCommand(q_c=q_c, thrust_N=thrust_N, omega_c_B=omega), None, ""
