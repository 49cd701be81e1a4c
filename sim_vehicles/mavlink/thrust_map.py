"""The one map between a collective thrust [N] and SET_ATTITUDE_TARGET's ``thrust`` field.

Neither autopilot has a parameter for the vehicle's largest thrust or its mass; both have one for
the thrust that hovers it, as a fraction of the most the rotors give: PX4's ``MPC_THR_HOVER``
(``mc_pos_control``, "Vertical thrust required to hover"), ArduPilot's ``MOT_THST_HOVER``
(``AP_MotorsMulticopter``, "Motor thrust needed to hover expressed as a number from 0 to 1").
Both read the field as that same collective thrust, normalised: PX4's ``fill_thrust`` makes it
the body thrust setpoint ``-thrust`` (``mavlink_receiver.cpp``); ArduCopter, with bit 3 of
``GUID_OPTIONS`` set (``SetAttitudeTarget_ThrustAsThrust``), takes it as the throttle of its
attitude controller (``ModeGuided::angle_control_run``), which is thrust, not motor command: its
motors turn it into motor commands through the thrust curve ``MOT_THST_EXPO``
(``AP_MotorsMulticopter::thrust_to_actuator``), so the curve never enters this map. So, with the
mass from the config and gravity:

    field = hover * F / (m g)            (F: the thrust asked for [N])

and a vehicle whose rotors give ``T_max`` at full thrust hovers at ``hover = m g / T_max``
(``hover_fraction``, what our vehicles serve): ``F = field * T_max``, the same map read back.
``full_thrust_N`` is the ``m g / hover`` a controller divides by.

**ArduCopter's angle boost.** ArduCopter sets its throttle through
``set_throttle_out(thrust, apply_angle_boost=true, ...)``; with ``ATC_ANGLE_BOOST`` on (its
default) the throttle is divided by the cosine of the vehicle's tilt (at most by 1/0.1), and cut
to zero as the vehicle turns over (``AC_AttitudeControl_Multi::get_throttle_boosted``: times
``clamp(10 cos_tilt, 0, 1)``), then held to 0..1 by the motors. A controller that means a
thrust ``F`` along its body axis therefore asks for ``F cos(tilt)`` (``boost_compensated``), its
commanded attitude's tilt standing for the vehicle's; the vehicle applies the boost with its own
(``boosted_throttle``).
"""

import math
from collections.abc import Sequence

import numpy as np

#: the boost's floor on cos(tilt) (ArduCopter: ``constrain_float(cos_tilt_target, 0.1, 1.0)``)
BOOST_MIN_COS = 0.1


def hover_fraction(mass_kg: float, g_mps2: float, max_thrust_N: float) -> float:
    """The thrust field that hovers a vehicle of ``mass_kg`` whose full thrust is ``max_thrust_N``
    (what ``MPC_THR_HOVER`` and ``MOT_THST_HOVER`` hold for it)."""
    return mass_kg * g_mps2 / max_thrust_N


def full_thrust_N(mass_kg: float, g_mps2: float, hover: float) -> float:
    """The thrust [N] a field of 1.0 means to a controller: ``m g / hover``."""
    return mass_kg * g_mps2 / hover


def field_of_thrust(thrust_N: float, full_N: float) -> float:
    """The ``thrust`` field for ``thrust_N``, clipped to 0..1 (the wire kernels do the same:
    ``wire_format.attitude_target_fields``)."""
    return min(max(thrust_N / full_N, 0.0), 1.0)


def cos_tilt(q_wxyz: Sequence[float] | np.ndarray) -> float:
    """The cosine of the angle between a body's z axis and the world's vertical, for the body
    attitude ``q`` (Hamilton ``[w, x, y, z]``, body to world; ENU/FLU or NED/FRD alike): the
    ``R[2][2]`` entry, ``1 - 2 (x^2 + y^2)`` of the unit quaternion."""
    w, x, y, z = q_wxyz
    n2 = w * w + x * x + y * y + z * z
    return 1.0 - 2.0 * (x * x + y * y) / n2


def boost_compensated(thrust_N: float, q_c: Sequence[float] | np.ndarray) -> float:
    """The thrust to ask an ArduCopter with angle boost on for, so that it gives ``thrust_N``
    at the tilt of the commanded attitude ``q_c``: ``thrust_N`` times that tilt's cosine (at
    least ``BOOST_MIN_COS``, as the boost's own floor)."""
    return thrust_N * max(cos_tilt(q_c), BOOST_MIN_COS)


def boosted_throttle(throttle: float, cos_tilt_now: float) -> float:
    """ArduCopter's throttle out for ``throttle`` in, at the vehicle's tilt now
    (``get_throttle_boosted``), held to 0..1 as its motors hold it."""
    inverted = min(max(10.0 * cos_tilt_now, 0.0), 1.0)
    boost = 1.0 / min(max(cos_tilt_now, BOOST_MIN_COS), 1.0)
    return min(max(throttle * inverted * boost, 0.0), 1.0)


def is_unit_length(q: Sequence[float] | np.ndarray) -> bool:
    """ArduPilot's test of a SET_ATTITUDE_TARGET quaternion (``Quaternion::is_unit_length``):
    its squared length within 1e-3 of 1."""
    n2 = sum(v * v for v in q)
    return math.isfinite(n2) and abs(n2 - 1.0) < 1e-3
