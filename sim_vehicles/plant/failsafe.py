"""What the vehicle flies on its own when its setpoints stop: its setpoint-loss failsafe.

PX4 leaves offboard when its setpoint stream stops for COM_OF_LOSS_T and flies the action of
COM_OBL_RC_ACT; so does this vehicle, with two actions (the parameter ``COM_OBL_RC_ACT``: 5 Hold,
4 Land; ``failsafe.ACTION_*`` here):

- ``ACTION_HOLD`` (1, the default): a position hold at the point of loss, with the vehicle's own
  position loop (a critically damped PD on the position error, ``HOLD_KP``/``HOLD_KD``, tilt
  limited to ``MAX_TILT_RAD``), heading kept;
- ``ACTION_LAND`` (0): the same loop holding the horizontal position while the setpoint descends
  at ``LAND_SPEED_MPS`` (PX4's MPC_LAND_SPEED; ``land_speed_mps`` for another autopilot's). The
  simulation has no ground: it keeps descending.

An ArduCopter flies two more on its own (``vehicle.autopilots``):

- ``ACTION_LEVEL``: level at its heading and its altitude held, nothing done about its horizontal
  drift: GUIDED_NOGPS with no setpoint or past ``GUID_TIMEOUT`` (``ModeGuided::angle_control_run``:
  a level attitude, climb rate 0), and STABILIZE with no pilot (the simulation has no RC);
- a climb rate under a commanded attitude (``climb_command``): SET_ATTITUDE_TARGET's thrust read
  as a climb rate (``GUID_OPTIONS`` bit 3 clear), its altitude target moving at that rate.

``failsafe_command`` and ``climb_command`` are pure: state in, attitude command out. The endpoint
calls them every ``FAILSAFE_PERIOD_S`` of simulated time while the vehicle flies on its own.
"""

import math
from typing import NamedTuple

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import qmul, rotation_matrix
from sim_vehicles.common.state import POS, QUAT, VEL
from sim_vehicles.plant.params import VehicleParams

ACTION_LAND = 0
ACTION_HOLD = 1
ACTION_LEVEL = 2  #: level, altitude held, no horizontal hold (ArduCopter's, not a config's choice)
ACTIONS = {"land": ACTION_LAND, "hold": ACTION_HOLD}  #: the config's ``failsafe_action``
ACTION_NAMES = {ACTION_LAND: "land", ACTION_HOLD: "hold", ACTION_LEVEL: "level"}

HOLD_KP = 4.0  #: position gain [1/s^2]
HOLD_KD = 4.0  #: velocity gain [1/s] (critically damped with HOLD_KP)
MAX_TILT_RAD = math.radians(30.0)
LAND_SPEED_MPS = 0.7
FAILSAFE_PERIOD_S = 0.01  #: how often the failsafe's position loop runs [s of simulated time]


class Hold(NamedTuple):
    """Where the failsafe started: position [m; ENU], heading [rad from east], time [s]."""

    p_W: np.ndarray
    yaw_rad: float
    t_s: float


def hold_at(state: np.ndarray, t_s: float) -> Hold:
    """The hold point of a failsafe entered now, in ``state``."""
    x_w = rotation_matrix(state[QUAT])[:, 0]
    return Hold(state[POS].copy(), math.atan2(x_w[1], x_w[0]), t_s)


def attitude_for(acc_W: np.ndarray, yaw_rad: float) -> np.ndarray:
    """The attitude whose body z axis is along ``acc_W`` (non-zero), at heading ``yaw_rad``:
    the heading's rotation, then the tilt from ``e3`` onto ``acc_W`` in the heading's frame."""
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    z = acc_W / np.linalg.norm(acc_W)
    zx, zy = cy * z[0] + sy * z[1], -sy * z[0] + cy * z[1]  # in the heading's frame
    sigma = math.sqrt(max(0.5 * (1.0 + z[2]), 1e-12))
    tilt = np.array([sigma, -zy / (2 * sigma), zx / (2 * sigma), 0.0])
    yaw = np.array([math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)])
    q = qmul(yaw, tilt)
    return q / np.linalg.norm(q)


def failsafe_command(
    state: np.ndarray,
    hold: Hold,
    t_s: float,
    action: int,
    p: VehicleParams,
    land_speed_mps: float = LAND_SPEED_MPS,
) -> AttitudeCommand:
    """The command of the failsafe ``action`` at ``t_s``, for the vehicle in ``state``."""
    target = hold.p_W.copy()
    v_ref = np.zeros(3)
    if action == ACTION_LAND:
        target[2] -= land_speed_mps * (t_s - hold.t_s)
        v_ref[2] = -land_speed_mps
    acc = -HOLD_KP * (state[POS] - target) - HOLD_KD * (state[VEL] - v_ref)
    if action == ACTION_LEVEL:  # its altitude only: it drifts as it goes
        acc[0:2] = 0.0
    acc[2] += p.g_mps2
    acc[2] = max(acc[2], 0.2 * p.g_mps2)  # never command a dive
    horizontal = math.hypot(acc[0], acc[1])
    limit = acc[2] * math.tan(MAX_TILT_RAD)
    if horizontal > limit:
        acc[0:2] *= limit / horizontal
    thrust = min(p.mass_kg * float(np.linalg.norm(acc)), p.max_thrust_N)
    return AttitudeCommand(q_c=attitude_for(acc, hold.yaw_rad), thrust_N=thrust)


def climb_command(
    state: np.ndarray, q_c: np.ndarray, hold: Hold, t_s: float, climb_mps: float, p: VehicleParams
) -> AttitudeCommand:
    """Attitude ``q_c`` held, the thrust that keeps the altitude on a target climbing at
    ``climb_mps`` from ``hold`` (its altitude and time): the vertical part of the hold's loop,
    divided by the tilt's cosine (at least 0.1) so the thrust's vertical part is what it asks."""
    z_ref = hold.p_W[2] + climb_mps * (t_s - hold.t_s)
    acc_z = -HOLD_KP * (state[POS][2] - z_ref) - HOLD_KD * (state[VEL][2] - climb_mps) + p.g_mps2
    c = float(rotation_matrix(q_c)[2, 2])
    thrust = min(max(p.mass_kg * acc_z / max(c, 0.1), 0.0), p.max_thrust_N)
    return AttitudeCommand(q_c=q_c, thrust_N=thrust)
