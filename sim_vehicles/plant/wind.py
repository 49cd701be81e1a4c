"""The air a vehicle flies in: a mean wind plus seeded turbulence, and the drag it makes.

The wind at a vehicle is ``mean_mps`` plus gusts: on each axis a first-order Gauss-Markov process
(seeded coloured noise, the form of the Dryden model's longitudinal component, with one correlation
time) sampled every ``WIND_DT_S``:

    g[k+1] = a g[k] + gust_mps sqrt(1 - a^2) n[k],   a = exp(-WIND_DT_S / gust_time_s)

with ``n[k]`` standard normal draws of (seed, system id, k) and ``g[0]`` drawn from the process's
stationary law, so each axis's gust has standard deviation ``gust_mps`` and autocorrelation
``exp(-|lag| / gust_time_s)`` at any time. An advance of the plant flies the wind of the instant
it starts (``Autopilot.advance``: a control period, in lockstep and in ``sim`` alike).

The air pushes the vehicle with quadratic drag, ``F = -drag_Ns2pm2 |v - w| (v - w)`` (``rigid_body``:
``drag_Ns2pm2`` is ``rho C_d A / 2``), so in a steady wind a free vehicle's velocity relative to the
air decays as ``u(t) = u0 / (1 + drag u0 t / m)``. Pure: the wind at sample k is a function of
the model and k.

``WindModel`` is each vehicle's own air (its gusts seeded by its system id: vehicles a metre apart
feel unrelated gusts); ``FrozenGusts`` is the world's (one gust field, carried by the mean wind:
neighbours feel the same gust). Either is asked ``update(t, position)`` for the wind where the
vehicle is.
"""

import math
from dataclasses import dataclass, field

import numpy as np

WIND_DT_S = 0.01  #: the gusts' sample period [s]


@dataclass
class WindModel:
    """Vehicle ``system_id``'s wind: ``at(t_s)`` [m/s; world ENU]."""

    system_id: int
    mean_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_mps: float = 0.0  #: standard deviation of each axis's gust [m/s]
    gust_time_s: float = 1.0  #: correlation time of the gusts [s]
    seed: int = 0
    #: the newest gust sample asked for, and its index (the chain goes on from it; one asked for
    #: before it is drawn again from the chain's start)
    _last: tuple[int, np.ndarray] | None = field(default=None, repr=False)

    def update(self, t_s: float, position_m: np.ndarray) -> np.ndarray:
        """The wind at time ``t_s`` where the vehicle is (RotorPy's winds' call): here the same
        anywhere, each vehicle's own (a new array)."""
        return self.at(t_s)

    def index(self, t_s: float) -> int:
        """The gust sample in force at ``t_s``."""
        return math.floor(t_s / WIND_DT_S + 1e-9)

    def at(self, t_s: float) -> np.ndarray:
        """The wind at ``t_s`` (a new array)."""
        w = np.array(self.mean_mps, dtype=float)
        if self.gust_mps > 0:
            w += self.gust(self.index(t_s))
        return w

    def gust(self, k: int) -> np.ndarray:
        """Gust sample ``k`` (>= 0), the chain carried on from the last one asked for (a flight
        asks in time order: nothing of a long run is kept but its newest sample)."""
        if self._last is None or k < self._last[0]:
            j, g = 0, self.gust_mps * self._normal(0)
        else:
            j, g = self._last
        a = math.exp(-WIND_DT_S / self.gust_time_s)
        while j < k:
            j += 1
            g = a * g + self.gust_mps * math.sqrt(1 - a * a) * self._normal(j)
        self._last = (j, g)
        return g

    def _normal(self, k: int) -> np.ndarray:
        return np.random.default_rng([self.seed, self.system_id, k, 77]).standard_normal(3)


@dataclass
class FrozenGusts(WindModel):
    """The world's gusts, one field for every vehicle (Taylor's frozen turbulence): the gust
    series of ``WindModel`` (seeded by the world alone, ``system_id`` 0) carried along by the
    mean wind ``W``, so a vehicle at ``p`` feels at ``t`` the gust of ``tau = t - (p . W) / |W|^2``
    (``WindModel.gust`` at ``tau``'s sample). Two vehicles level across the wind feel the same
    gust at once; one ``d`` metres downstream feels it ``d / |W|`` seconds later. In still mean air
    every vehicle feels the same gust at the same time. Before the field's first sample has
    reached a vehicle (``tau < 0``) it feels that first sample.

    Each vehicle (process or ``sim``) holds its own instance; they agree because the field is a
    pure function of the seed and ``tau``."""

    system_id: int = 0

    def update(self, t_s: float, position_m: np.ndarray) -> np.ndarray:
        w = np.array(self.mean_mps, dtype=float)
        if self.gust_mps > 0:
            speed2 = float(w @ w)
            tau = t_s - float(np.asarray(position_m, dtype=float) @ w) / speed2 if speed2 > 0 else t_s
            w += self.gust(max(0, self.index(tau)))
        return w


#: the wind models a config may name (``wind.model``): each vehicle's own gusts, or the world's
WIND_MODELS = {"independent": WindModel, "frozen": FrozenGusts}
