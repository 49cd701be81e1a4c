"""Loss and delay that grow with distance: a log-distance path-loss model with shadow fading and
link-layer retries, as DARPA SubT's comms model and Gazebo's RF plugin have it.

The received power at distance ``d`` from the sender is ``P(d) = P_tx - L0 - 10 n log10(d) + X``
(``n`` the path-loss exponent, ``X ~ N(0, sigma^2)`` dB the fading of one attempt). An attempt
gets through when ``P(d)`` reaches the receiver's sensitivity. Written with the range ``R`` at
which the mean power just reaches it (``P_tx - L0 - 10 n log10(R) = sensitivity``), the margin is

    margin(d) = 10 n log10(R / d)  [dB]

and one attempt fails with probability

    q(d) = Phi(-margin(d) / sigma) = Phi(10 n log10(d / R) / sigma)

(``Phi`` the standard normal CDF); with ``sigma = 0`` it fails exactly beyond ``R``. A message is
sent up to ``1 + retries`` times, ``retry_s`` apart (a radio's ARQ), each attempt fading
independently, so it is lost with probability ``q(d) ** (1 + retries)`` and, when it gets
through at attempt ``a`` (0 the first), comes ``a * retry_s`` late:

    P(lost) = q^(1 + r),    P(delay = a * retry_s) = q^a (1 - q),  a = 0..r

``d`` is the distance between the sender's and the receiver's positions at the tick the message
was sent for (the sender's travels with its message, ``bus.codec``; the receiver keeps its own).
Each attempt's draw is ``uniform(seed, entry, channel, step, salt + a)``: a pure function of the
run's inputs, so lockstep runs stay byte for byte the same.
"""

import math
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from swarm_sitl.faults.draws import uniform
from swarm_sitl.faults.link_model import HARSHER_WHEN_SMALLER, Effect, MessageOnLink

_ATTEMPT = 16  #: salt of attempt 0's draw (attempt a: 16 + a; the plan's other draws use 1..5)
_NEAR_M = 1e-9  #: distances are clamped up to this (two nodes at one point: the margin is finite)


class PathLoss(BaseModel):
    """``range:`` of a plan entry: loss and delay with distance (the module's formulas)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    #: where the mean power meets the sensitivity (R) [m]
    range_m: Annotated[float, Field(gt=0), HARSHER_WHEN_SMALLER]
    exponent: Annotated[float, Field(gt=0, le=10)] = 2.0  #: path-loss exponent n (2: free space)
    fading_db: Annotated[float, Field(ge=0, le=40)] = 0.0  #: spread sigma of each attempt's fading [dB]
    retries: Annotated[int, Field(ge=0, le=15)] = 0  #: attempts after the first one, if it fails
    retry_s: Annotated[float, Field(ge=0, le=1)] = 0.0  #: time between attempts [s]

    def attempt_loss(self, distance_m: float) -> float:
        """``q(d)``: the probability that one attempt at ``distance_m`` fails."""
        x = 10.0 * self.exponent * math.log10(max(distance_m, _NEAR_M) / self.range_m)
        if self.fading_db == 0:
            return 1.0 if x > 0 else 0.0
        return 0.5 * math.erfc(-x / (self.fading_db * math.sqrt(2.0)))

    def loss(self, distance_m: float) -> float:
        """The probability that a message at ``distance_m`` is lost (every attempt fails)."""
        return self.attempt_loss(distance_m) ** (1 + self.retries)

    def mean_delay_s(self, distance_m: float) -> float:
        """The mean delay of a message at ``distance_m`` that gets through [s]."""
        q = self.attempt_loss(distance_m)
        if q == 1.0:
            return math.nan  # none gets through
        weights = [q**a for a in range(self.retries + 1)]  # (each times 1 - q: it cancels)
        return self.retry_s * sum(a * w for a, w in enumerate(weights)) / sum(weights)

    def attempts(self, distance_m: float, seed: int, entry: int, channel: int, step: int) -> int:
        """How many attempts a message needs (1 .. 1 + retries), or 0: every one failed."""
        q = self.attempt_loss(distance_m)
        for a in range(self.retries + 1):
            if uniform(seed, entry, channel, step, _ATTEMPT + a) >= q:
                return a + 1
        return 0

    def describe(self) -> str:
        tail = f", {self.retries} retries {self.retry_s:g} s apart" if self.retries else ""
        return f"range {self.range_m:g} m (exponent {self.exponent:g}, fading {self.fading_db:g} dB{tail})"


def distance_m(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    """The distance between two points [m]."""
    return math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)


class Range:
    """The link model of ``range:``: lost when every attempt fails at the message's distance,
    else late by the retries it took."""

    Params = PathLoss
    plan_form = "params"  #: ``range: {range_m, ...}`` (``link_models``)
    needs_distance = True  #: (its severity then depends on where the swarm flies: none declared)

    def fate(self, p: PathLoss, m: MessageOnLink) -> Effect | None:
        assert not math.isnan(m.distance_m), "a range entry needs the distance"
        attempts = p.attempts(m.distance_m, m.seed, m.entry, m.channel, m.step)
        if attempts == 0:
            return OUT_OF_RANGE
        if attempts == 1:
            return None
        return Effect(delay_s=(attempts - 1) * p.retry_s, retried=True)


OUT_OF_RANGE = Effect(lost=True, out_of_range=True)
