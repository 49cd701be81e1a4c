"""Leader reference trajectories with analytic derivatives up to the fourth (snap).

``derivatives(t)`` returns an array of shape ``(5, 3)``, or ``(len(t), 5, 3)`` for an array ``t``:
position [m], velocity [m/s], acceleration [m/s^2], jerk [m/s^3] and snap [m/s^4], world ENU.
"""

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


class Trajectory(Protocol):
    def derivatives(self, t_s: float | np.ndarray) -> np.ndarray: ...


def _time(t_s: float | np.ndarray) -> tuple[Any, Any, Any]:
    """``(t, sin, zero)``: scalar math for a float (fast per-tick path), numpy for arrays."""
    if isinstance(t_s, float | int) or np.ndim(t_s) == 0:  # np.ndim alone costs a dispatch per tick
        return float(t_s), math.sin, 0.0
    t = np.asarray(t_s, dtype=float)
    return t, np.sin, np.zeros_like(t)


def _stack(cols: list[list[Any]]) -> np.ndarray:
    """(order, axis, ...) -> (..., order, axis)."""
    arr = np.array(cols, dtype=float)  # (5, 3, *t)
    return arr if arr.ndim == 2 else np.moveaxis(arr, (0, 1), (-2, -1))


def _sin_derivs(amp: float, rate: float, phase: Any, sin: Any) -> list[Any]:
    """d^n/dt^n of amp * sin(phase(t)) with phase' = rate, n = 0..4."""
    return [amp * rate**n * sin(phase + n * math.pi / 2) for n in range(5)]


@dataclass(frozen=True)
class Helix:
    """``p(t) = c + [R cos(w t + phi), R sin(w t + phi), v_z t]``.

    The paper's section 4 is R = 5 m, w = 0.2 rad/s, v_z = 1 m/s.
    """

    radius_m: float
    angular_rate_radps: float
    climb_rate_mps: float
    center_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    phase_rad: float = 0.0

    def derivatives(self, t_s: float | np.ndarray) -> np.ndarray:
        t, sin, zero = _time(t_s)
        th = self.angular_rate_radps * t + self.phase_rad
        x = _sin_derivs(self.radius_m, self.angular_rate_radps, th + math.pi / 2, sin)  # R cos
        y = _sin_derivs(self.radius_m, self.angular_rate_radps, th, sin)
        z = [self.climb_rate_mps * t, self.climb_rate_mps + zero, zero, zero, zero]
        c = self.center_m
        cols = [
            [
                x[n] + (c[0] if n == 0 else 0.0),
                y[n] + (c[1] if n == 0 else 0.0),
                z[n] + (c[2] if n == 0 else 0.0),
            ]
            for n in range(5)
        ]
        return _stack(cols)


@dataclass(frozen=True)
class FigureEight:
    """Lemniscate of Gerono at constant altitude: ``p(t) = c + [A sin(w t), B sin(2 w t), 0]``."""

    amplitude_x_m: float
    amplitude_y_m: float
    angular_rate_radps: float
    center_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def derivatives(self, t_s: float | np.ndarray) -> np.ndarray:
        t, sin, zero = _time(t_s)
        w = self.angular_rate_radps
        x = _sin_derivs(self.amplitude_x_m, w, w * t, sin)
        y = _sin_derivs(self.amplitude_y_m, 2 * w, 2 * w * t, sin)
        c = self.center_m
        cols = [
            [
                x[n] + (c[0] if n == 0 else 0.0),
                y[n] + (c[1] if n == 0 else 0.0),
                zero + (c[2] if n == 0 else 0.0),
            ]
            for n in range(5)
        ]
        return _stack(cols)


@dataclass(frozen=True)
class Line:
    """Straight line at constant velocity: ``p(t) = p0 + v t``."""

    start_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]

    def derivatives(self, t_s: float | np.ndarray) -> np.ndarray:
        t, _, zero = _time(t_s)
        p0, v = self.start_m, self.velocity_mps
        cols = [[p0[a] + v[a] * t for a in range(3)], [v[a] + zero for a in range(3)]]
        cols += [[zero, zero, zero] for _ in range(3)]
        return _stack(cols)


def sup_norm(traj: Trajectory, order: int, horizon_s: float, samples: int = 20001) -> float:
    """``sup |p_r^(order)(t)|`` over ``[0, horizon_s]`` on a dense grid (exact for the shapes here)."""
    t = np.linspace(0.0, horizon_s, samples)
    d = traj.derivatives(t)[:, order, :]
    return float(np.max(np.linalg.norm(d, axis=1)))


def sup_Np(traj: Trajectory, l_a: float, horizon_s: float, samples: int = 20001) -> float:
    """``sup |N_p(t)|`` with ``N_p = l_a p_r^(3) - p_r^(4)`` (Theorem 1)."""
    t = np.linspace(0.0, horizon_s, samples)
    d = traj.derivatives(t)
    return float(np.max(np.linalg.norm(l_a * d[:, 3, :] - d[:, 4, :], axis=1)))
