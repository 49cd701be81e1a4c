"""ENU/FLU <-> NED/FRD conversions. Used only where MAVLink messages are built and read.

Internal: world ENU (x east, y north, z up), body FLU (x forward, y left, z up).
MAVLink:  world NED (x north, y east, z down), body FRD (x forward, y right, z down).
"""

import numpy as np

_S = np.sqrt(0.5)
#: rotation taking ENU coordinates to NED coordinates (x<->y, z -> -z)
Q_NED_ENU = np.array([0.0, _S, _S, 0.0])
#: rotation taking FRD body coordinates to FLU body coordinates (180 deg about x)
Q_FLU_FRD = np.array([0.0, 1.0, 0.0, 0.0])


def enu_to_ned(v: np.ndarray) -> np.ndarray:
    """World vector ENU -> NED (also NED -> ENU: the map is its own inverse)."""
    v = np.asarray(v, dtype=float)
    return np.array([v[1], v[0], -v[2]])


ned_to_enu = enu_to_ned


def flu_to_frd(v: np.ndarray) -> np.ndarray:
    """Body vector FLU -> FRD (its own inverse)."""
    v = np.asarray(v, dtype=float)
    return np.array([v[0], -v[1], -v[2]])


frd_to_flu = flu_to_frd


_S_FLOAT = float(_S)


def swap_frames_wxyz(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """``Q_NED_ENU (x) q (x) Q_FLU_FRD`` for ``q = (w, x, y, z)``, closed form, sign chosen with
    w >= 0. The same map takes FLU->ENU attitudes to FRD->NED and back (it is its own inverse up
    to sign). Plain floats in and out: the wire's per-message paths build no array for it."""
    s = _S_FLOAT if w + z >= 0 else -_S_FLOAT
    return (s * (w + z), s * (x + y), s * (x - y), s * (w - z))


def _swap_frames(q: np.ndarray) -> np.ndarray:
    return np.array(swap_frames_wxyz(float(q[0]), float(q[1]), float(q[2]), float(q[3])))


def q_enu_flu_to_ned_frd(q_WB: np.ndarray) -> np.ndarray:
    """Attitude FLU->ENU to attitude FRD->NED."""
    return _swap_frames(q_WB)


def q_ned_frd_to_enu_flu(q_NED_FRD: np.ndarray) -> np.ndarray:
    """Attitude FRD->NED to attitude FLU->ENU."""
    return _swap_frames(q_NED_FRD)
