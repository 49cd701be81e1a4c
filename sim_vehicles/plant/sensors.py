"""What the vehicle reports of its state, as an autopilot's estimator gives it: the true state
some latency ago, plus seeded noise. Off by default (the report is the true state).

``SensorModel.reported(time_boot_ms, x)`` takes the true state ``x`` at a sample's
``time_boot_ms`` (simulated time) and returns the state the vehicle sends in LOCAL_POSITION_NED and
ATTITUDE_QUATERNION:

- latency: the true state of the last sample at or before ``t_s - latency_s`` (the first sample's
  until then), as a state estimate that lags;
- noise: independent zero-mean Gaussian errors, ``position_noise_m`` on each position axis,
  ``velocity_noise_mps`` on each velocity axis, and an attitude error rotation whose rotation
  vector has ``attitude_noise_rad`` on each axis (applied in the body frame), drawn from
  ``(seed, system id, time_boot_ms)``: the same run gets the same noise, whatever the machine does;
- a position bias that wanders (``position_bias_walk_m_per_sqrt_s``): a random walk sampled every
  ``BIAS_DT_S`` from zero at boot, its spread growing as the square root of time, as the estimate
  of a GNSS-aided autopilot drifts (``bias``), seeded as the noise is.

The truth files keep the true state, so a run's error plots stay true. Pure: no clock, no I/O.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from sim_vehicles.common.quaternion import from_axis_angle, qmul
from sim_vehicles.common.state import POS, QUAT, VEL

BIAS_DT_S = 0.01  #: the position bias's random-walk sample period [s]


@dataclass
class SensorModel:
    """Latency and noise of what vehicle ``system_id`` reports (``reported``)."""

    system_id: int
    position_noise_m: float = 0.0
    velocity_noise_mps: float = 0.0
    attitude_noise_rad: float = 0.0
    latency_s: float = 0.0
    seed: int = 0
    #: the position's bias, a random walk: it wanders by this much per sqrt(second) on each axis,
    #: as a GNSS-aided estimate drifts (its spread after t seconds: this times sqrt(t)) [m/sqrt(s)]
    position_bias_walk_m_per_sqrt_s: float = 0.0
    _history: list[tuple[float, np.ndarray]] = field(default_factory=list, repr=False)
    #: the newest bias sample asked for and its index (the walk goes on from it)
    _bias: tuple[int, np.ndarray] | None = field(default=None, repr=False)

    @property
    def active(self) -> bool:
        noise = (self.position_noise_m, self.velocity_noise_mps, self.attitude_noise_rad)
        return any(v > 0 for v in (*noise, self.position_bias_walk_m_per_sqrt_s))

    def reported(self, time_boot_ms: int, x: np.ndarray) -> np.ndarray:
        """The state a sample at ``time_boot_ms`` reports (a new array; ``x`` is not changed)."""
        y = self._delayed(time_boot_ms / 1000, x) if self.latency_s > 0 else x.copy()
        if not self.active:
            return y
        if self.position_bias_walk_m_per_sqrt_s > 0:
            y[POS] += self.bias(math.floor(time_boot_ms / 1000 / BIAS_DT_S + 1e-9))
        e = np.random.default_rng([self.seed, self.system_id, time_boot_ms]).standard_normal(9)
        y[POS] += self.position_noise_m * e[0:3]
        y[VEL] += self.velocity_noise_mps * e[3:6]
        if self.attitude_noise_rad > 0:
            v = self.attitude_noise_rad * e[6:9]  # a rotation vector
            angle = float(np.linalg.norm(v))  # (0 where a tiny noise's square underflows: no rotation)
            if angle > 0:
                y[QUAT] = qmul(y[QUAT], from_axis_angle(v, angle))
        return y

    def bias(self, k: int) -> np.ndarray:
        """The position bias of walk sample ``k`` (>= 0) [m; ENU]: ``b[0] = 0``, ``b[k] = b[k - 1]
        + walk sqrt(BIAS_DT_S) n[k]`` with ``n[k]`` standard normal draws of (seed, system id, k),
        carried on from the last one asked for (asked for earlier: drawn again from the start)."""
        if self._bias is None or k < self._bias[0]:
            j, b = 0, np.zeros(3)
        else:
            j, b = self._bias
        step = self.position_bias_walk_m_per_sqrt_s * math.sqrt(BIAS_DT_S)
        while j < k:
            j += 1
            b = b + step * np.random.default_rng([self.seed, self.system_id, j, 91]).standard_normal(3)
        self._bias = (j, b)
        return b

    def _delayed(self, t_s: float, x: np.ndarray) -> np.ndarray:
        """The true state of the newest sample at or before ``t_s - latency_s`` (the oldest kept
        if none is that old yet); older ones are dropped (times only grow)."""
        h = self._history
        if not h or t_s > h[-1][0]:
            h.append((t_s, x.copy()))
        cut = t_s - self.latency_s + 1e-9
        chosen = next((i for i in range(len(h) - 1, -1, -1) if h[i][0] <= cut), 0)
        del h[:chosen]
        return h[0][1].copy()
