"""Leader reference trajectories with analytic derivatives up to the fourth (snap).

``derivatives(t)`` returns an array of shape ``(5, 3)``, or ``(len(t), 5, 3)`` for an array ``t``:
position [m], velocity [m/s], acceleration [m/s^2], jerk [m/s^3] and snap [m/s^4], world ENU.
"""

import math
from collections.abc import Callable
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


def period_s(traj: Trajectory) -> float | None:
    """The period of ``traj``'s derivatives from the velocity on (the helix climbs, its
    derivatives repeat), or None where they are constant (a line, a helix that does not turn)."""
    if isinstance(traj, Helix | FigureEight) and traj.angular_rate_radps != 0:
        return 2 * math.pi / abs(traj.angular_rate_radps)
    return None


def N_p(traj: Trajectory, l_a: float, t_s: float | np.ndarray) -> np.ndarray:
    """``N_p = -l_a p_r^(3) - p_r^(4)`` as derived from the estimator (docs/paper.md, erratum 8: the paper
    prints ``+l_a``), at ``t_s``."""
    d = traj.derivatives(t_s)
    return -l_a * d[..., 3, :] - d[..., 4, :]


def _sup(
    traj: Trajectory,
    f: Callable[[np.ndarray], np.ndarray],
    horizon_s: float,
    samples: int,
    periodic: bool = True,
) -> float:
    """``sup_t |f(t)|``: over one period where the derivatives repeat (so for all time), the grid's
    best point refined by golden-section search to the float's precision; else over
    ``[0, horizon_s]`` (where the derivatives are constant, exactly)."""
    period = period_s(traj) if periodic else None
    t = np.linspace(0.0, period if period is not None else horizon_s, samples)
    norms = np.linalg.norm(f(t), axis=-1)
    k = int(np.argmax(norms))
    best = float(norms[k])
    if period is None:
        return best
    # one grid step either side; past the period's ends is the next period (a peak just before
    # t = period has its best grid point at t = 0, and its bracket must reach back over the end)
    step = t[1] - t[0]
    lo, hi = t[k] - step, t[k] + step
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):  # the bracket shrinks by 0.618 a step: far below a float's spacing
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        fa, fb = np.linalg.norm(f(np.array([a, b])), axis=-1)
        if fa >= fb:
            hi = b
        else:
            lo = a
        best = max(best, float(fa), float(fb))
    return best


def sup_norm(traj: Trajectory, order: int, horizon_s: float, samples: int = 20001) -> float:
    """``sup |p_r^(order)(t)|`` for all time where the derivatives are periodic (order 1 on: a
    helix's position is not), else over ``[0, horizon_s]``."""
    return _sup(traj, lambda t: traj.derivatives(t)[:, order, :], horizon_s, samples, periodic=order > 0)


def sup_Np(traj: Trajectory, l_a: float, horizon_s: float, samples: int = 20001) -> float:
    """``sup |N_p(t)|`` (``N_p`` as derived), as ``sup_norm`` takes it (Theorem 1's ``k_a`` bound)."""
    return _sup(traj, lambda t: N_p(traj, l_a, t), horizon_s, samples)
