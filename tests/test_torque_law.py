"""The attitude loop: J rdot = -k_q r, and a 90-degree error brought to zero."""

import numpy as np
import pytest

from sim_vehicles.autopilot import AttitudeCommand, Autopilot
from sim_vehicles.params import AttitudeGains, VehicleParams
from sim_vehicles.quaternion import from_axis_angle, qmul
from sim_vehicles.rigid_body import QUAT, RATE, make_state, rk4_step
from sim_vehicles.torque_law import attitude_error, torque

pytestmark = pytest.mark.unit
PARAMS = VehicleParams(0.85, (4.856e-2, 4.856e-2, 8.801e-2), 25.0)
J = PARAMS.inertia
L_Q = K_Q = 16.0


def test_ninety_degree_error_goes_to_zero():
    ap = Autopilot(PARAMS, AttitudeGains(L_Q, K_Q), make_state([0, 0, 0.0]), 1e-3)
    q_c = from_axis_angle([1.0, 1.0, 0.0], np.pi / 2)
    ap.set_command(AttitudeCommand(q_c=q_c, thrust_N=0.0))
    angle = []
    for _ in range(30):
        ap.advance(100)
        q_e, _w_e, _ = attitude_error(ap.state[QUAT], ap.state[RATE], q_c, np.zeros(3))
        angle.append(2 * np.arccos(min(1.0, abs(q_e[0]))))
    assert angle[0] < np.pi / 2  # it moved toward the target
    assert angle[4] < np.radians(45)  # half the error gone in 0.5 s (q_e decays at about l_q / 2)
    assert angle[-1] < 1e-4 and np.linalg.norm(ap.state[RATE]) < 1e-3


def test_sliding_surface_decays_as_j_rdot_equals_minus_kq_r():
    """With a rotating command (omega_c, omegadot_c known), r = l_q q_e + omega_e obeys J rdot = -k_q r.

    Catches any sign error between R(Q), the error quaternion and the torque law (NOTES.md error 4).
    """
    dt = 1e-4
    w_cmd = np.array([0.3, -0.2, 0.5])  # constant command body rate
    q_c0 = from_axis_angle([0.3, 1.0, 0.2], 0.4)
    x = make_state([0, 0, 0.0], q_wb=from_axis_angle([1.0, 0, 0], 0.8), omega_radps=[0.5, 0.0, -0.4])

    def command(t):
        return qmul(q_c0, from_axis_angle(w_cmd, np.linalg.norm(w_cmd) * t))

    def r_of(x, t):
        q_e, w_e, _ = attitude_error(x[QUAT], x[RATE], command(t), w_cmd)
        return L_Q * q_e[1:] + w_e

    r0 = r_of(x, 0.0)
    for k in range(1, 2001):
        t0 = (k - 1) * dt
        tau = torque(x[QUAT], x[RATE], command(t0), w_cmd, np.zeros(3), J, L_Q, K_Q)
        x = rk4_step(x, 0.0, tau, PARAMS.mass_kg, J, 0.0, dt)
        if k % 500 == 0:
            t = k * dt
            expected = r0 * np.exp(-K_Q / J * t)
            # torque is held over each step: agreement to first order in dt
            np.testing.assert_allclose(r_of(x, t), expected, atol=2e-3 * np.linalg.norm(r0))
