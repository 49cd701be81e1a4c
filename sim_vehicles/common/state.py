"""The state vector of a vehicle's rigid body: 13 float64, the only place its layout is defined.

- ``x[POS]``  position ``p_W`` [m; world ENU]
- ``x[VEL]``  velocity ``v_W`` [m/s; world ENU]
- ``x[QUAT]`` attitude ``q_WB`` [Hamilton w,x,y,z; body FLU -> world ENU]
- ``x[RATE]`` body rates ``omega_B`` [rad/s; body FLU]

Compiled kernels slice with the same globals (numba folds them into constants: the machine code is
that of a literal ``x[6:10]``); one component is ``x[VEL0 + 2]``. ``STATE_COLUMNS`` names the
entries where a state is written as a row, ``TRUTH_COLUMNS`` a vehicle's truth log's.
"""

import numpy as np

STATE_SIZE = 13
POS0, VEL0, QUAT0, RATE0 = 0, 3, 6, 10  #: where each part starts
POS = slice(POS0, POS0 + 3)
VEL = slice(VEL0, VEL0 + 3)
QUAT = slice(QUAT0, QUAT0 + 4)
RATE = slice(RATE0, RATE0 + 3)
STATE_COLUMNS = ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "wx", "wy", "wz")
#: a truth log's row (what a vehicle writes and a run directory merges): the vehicle's boot time
#: [s], then its true state
TRUTH_COLUMNS = ["time_boot_s", *STATE_COLUMNS]


def make_state(
    position_m, velocity_mps=(0.0, 0.0, 0.0), q_wb=(1.0, 0.0, 0.0, 0.0), omega_radps=(0.0, 0.0, 0.0)
) -> np.ndarray:
    """Assemble a state vector from named parts."""
    x = np.empty(STATE_SIZE)
    x[POS] = position_m
    x[VEL] = velocity_mps
    x[QUAT] = q_wb
    x[RATE] = omega_radps
    return x
