"""What the vehicle flies on its own when its setpoints stop: its setpoint-loss failsafe.

PX4 leaves offboard when its setpoint stream stops for COM_OF_LOSS_T and flies the action of
COM_OBL_ACT; so does this vehicle, with two actions (the parameter ``COM_OBL_ACT``, PX4's values):

- ``ACTION_HOLD`` (1, the default): a position hold at the point of loss, with the vehicle's own
  position loop (a critically damped PD on the position error, ``HOLD_KP``/``HOLD_KD``, tilt
  limited to ``MAX_TILT_RAD``), heading kept;
- ``ACTION_LAND`` (0): the same loop holding the horizontal position while the setpoint descends
  at ``LAND_SPEED_MPS`` (PX4's MPC_LAND_SPEED). The simulation has no ground: it keeps descending.

``failsafe_command`` is pure: state in, attitude command out. The endpoint calls it every
``FAILSAFE_PERIOD_S`` of simulated time while in failsafe.
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
ACTIONS = {"land": ACTION_LAND, "hold": ACTION_HOLD}

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
    state: np.ndarray, hold: Hold, t_s: float, action: int, p: VehicleParams
) -> AttitudeCommand:
    """The command of the failsafe ``action`` at ``t_s``, for the vehicle in ``state``."""
    target = hold.p_W.copy()
    v_ref = np.zeros(3)
    if action == ACTION_LAND:
        target[2] -= LAND_SPEED_MPS * (t_s - hold.t_s)
        v_ref[2] = -LAND_SPEED_MPS
    acc = -HOLD_KP * (state[POS] - target) - HOLD_KD * (state[VEL] - v_ref)
    acc[2] += p.g_mps2
    acc[2] = max(acc[2], 0.2 * p.g_mps2)  # never command a dive
    horizontal = math.hypot(acc[0], acc[1])
    limit = acc[2] * math.tan(MAX_TILT_RAD)
    if horizontal > limit:
        acc[0:2] *= limit / horizontal
    thrust = min(p.mass_kg * float(np.linalg.norm(acc)), p.max_thrust_N)
    return AttitudeCommand(q_c=attitude_for(acc, hold.yaw_rad), thrust_N=thrust)
