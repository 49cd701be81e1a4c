"""What an attitude loop is asked to track: the controller's output and the vehicle's input.

The swarm's laws produce it, the MAVLink wire carries it (SET_ATTITUDE_TARGET: attitude, body
rates, thrust), the vehicle's attitude loop holds it until the next one.
"""

from typing import NamedTuple

import numpy as np

ZERO3 = np.zeros(3)
ZERO3.flags.writeable = False


class AttitudeCommand(NamedTuple):
    """What an attitude loop is asked to track, held until the next command."""

    q_c: np.ndarray  #: command attitude [Hamilton w,x,y,z; body FLU -> world ENU]
    thrust_N: float  #: collective thrust [N]
    omega_c_B: np.ndarray = ZERO3  #: command body rates [rad/s; command body frame]
    omegadot_c_B: np.ndarray = ZERO3  #: their derivative [rad/s^2]; zeros where unknown
