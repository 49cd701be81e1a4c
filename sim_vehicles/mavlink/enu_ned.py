"""ENU/FLU <-> NED/FRD: the one place where the two conventions meet.

Internal: world ENU (x east, y north, z up), body FLU (x forward, y left, z up).
MAVLink:  world NED (x north, y east, z down), body FRD (x forward, y right, z down).

Every conversion where MAVLink fields are built or read goes through this module (``wire_format``
for the messages the swarm uses, the vehicle's telemetry for the rest); nowhere else in either
package is NED or FRD written. Each map is its own inverse:

- a world vector: ``(x, y, z) -> (y, x, -z)`` (``enu_to_ned``, ``ned_to_enu``; ``world_into``);
- a body vector: ``(x, y, z) -> (x, -y, -z)`` (``flu_to_frd``, ``frd_to_flu``; ``body_into``);
- an attitude: ``Q_NED_ENU (x) q (x) Q_FLU_FRD``, in closed form, sign chosen with ``w >= 0``
  (``q_enu_flu_to_ned_frd``, ``q_ned_frd_to_enu_flu``, ``swap_frames_wxyz``; ``attitude_into``).

The ``*_into`` forms are compiled: they write into a kernel's array at an offset, so a per-tick
frame converts and packs in one compiled call (``tick_frames``). The Python forms do the same IEEE
operations in the same order.
"""

import math

import numpy as np

from sim_vehicles.common.jit import kernel

_S = math.sqrt(0.5)
#: rotation taking ENU coordinates to NED coordinates (x<->y, z -> -z)
Q_NED_ENU = np.array([0.0, _S, _S, 0.0])
#: rotation taking FRD body coordinates to FLU body coordinates (180 deg about x)
Q_FLU_FRD = np.array([0.0, 1.0, 0.0, 0.0])


# -- compiled ------------------------------------------------------------------------------------


@kernel
def world_into(out, at, v):
    """The world vector ``v`` ENU -> NED (or NED -> ENU) written to ``out[at:at + 3]``."""
    out[at] = v[1]
    out[at + 1] = v[0]
    out[at + 2] = -v[2]


@kernel
def body_into(out, at, v):
    """The body vector ``v`` FLU -> FRD (or FRD -> FLU) written to ``out[at:at + 3]``."""
    out[at] = v[0]
    out[at + 1] = -v[1]
    out[at + 2] = -v[2]


@kernel
def attitude_into(out, at, w, x, y, z):
    """The attitude ``(w, x, y, z)`` FLU -> ENU as FRD -> NED (or back) written to
    ``out[at:at + 4]``: ``swap_frames_wxyz``."""
    s = _S if w + z >= 0 else -_S
    out[at] = s * (w + z)
    out[at + 1] = s * (x + y)
    out[at + 2] = s * (x - y)
    out[at + 3] = s * (w - z)


# -- Python --------------------------------------------------------------------------------------


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


def swap_frames_wxyz(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """``Q_NED_ENU (x) q (x) Q_FLU_FRD`` for ``q = (w, x, y, z)``, closed form, sign chosen with
    w >= 0. The same map takes FLU->ENU attitudes to FRD->NED and back (it is its own inverse up
    to sign). Plain floats in and out."""
    s = _S if w + z >= 0 else -_S
    return (s * (w + z), s * (x + y), s * (x - y), s * (w - z))


def _swap_frames(q: np.ndarray) -> np.ndarray:
    return np.array(swap_frames_wxyz(float(q[0]), float(q[1]), float(q[2]), float(q[3])))


def q_enu_flu_to_ned_frd(q_WB: np.ndarray) -> np.ndarray:
    """Attitude FLU->ENU to attitude FRD->NED."""
    return _swap_frames(q_WB)


def q_ned_frd_to_enu_flu(q_NED_FRD: np.ndarray) -> np.ndarray:
    """Attitude FRD->NED to attitude FLU->ENU."""
    return _swap_frames(q_NED_FRD)
