"""Bursty loss: the Gilbert-Elliott model, as Linux netem's ``loss gemodel p r 1-h 1-k`` has it.

A link is in a good or a bad state. Each message (each step of its sender) it moves from good to
bad with probability ``p`` and from bad to good with probability ``r``, then the message is lost
with probability ``loss_bad`` (netem's 1-h, default 1) in the bad state and ``loss_good`` (netem's
1-k, default 0) in the good one. In the long run the link is bad a fraction ``p / (p + r)`` of the
time, so the mean loss is

    loss = (r * loss_good + p * loss_bad) / (p + r)

and, with ``loss_bad = 1`` and ``loss_good = 0``, losses come in bursts of mean length ``1 / r``
(geometric), separated by gaps of mean length ``1 / p``.

The chain is a pure function of the run's inputs: it starts good at step 0 and each step's
transition is a draw of ``uniform(seed, entry, channel, step, salt)``, so the state at a step (and
the message's fate) is the same whoever asks, in whatever order, after a restart too (``state_at``
keeps each chain's states as far as it was asked and extends it on demand).
"""

from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from swarm_sitl.faults.draws import uniform
from swarm_sitl.faults.link_model import HARSHER_WHEN_SMALLER, Effect, Effects, MessageOnLink, StepsOnLink
from swarm_sitl.faults.loss import DRAW, LOST

_STATE = 5  #: salt of the state-transition draws (``plan``'s loss draw is salt 1)


class GilbertElliott(BaseModel):
    """``bursty:`` of a plan entry: the Gilbert-Elliott loss model (netem's names in brackets)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    p: Annotated[float, Field(gt=0, le=1)]  #: good -> bad, per message [netem p]
    r: Annotated[float, Field(gt=0, le=1), HARSHER_WHEN_SMALLER]  #: bad -> good, per message [netem r]
    loss_bad: Annotated[float, Field(ge=0, le=1)] = 1.0  #: loss in the bad state [netem 1-h]
    loss_good: Annotated[float, Field(ge=0, le=1)] = 0.0  #: loss in the good state [netem 1-k]

    @model_validator(mode="after")
    def _loses_something(self) -> "GilbertElliott":
        if self.loss_bad == 0 and self.loss_good == 0:
            raise ValueError("loses nothing: loss_bad and loss_good are both 0")
        return self

    @property
    def mean_loss(self) -> float:
        """The long-run fraction of messages lost."""
        return (self.r * self.loss_good + self.p * self.loss_bad) / (self.p + self.r)

    @property
    def mean_burst(self) -> float:
        """The mean number of messages in a row in the bad state (``1 / r``)."""
        return 1.0 / self.r

    def describe(self) -> str:
        return (
            f"bursty p {self.p:g} r {self.r:g} (mean loss {self.mean_loss:.3g}, "
            f"bad runs of {self.mean_burst:.3g})"
        )


#: (seed, entry, channel, p, r) -> the chain's states so far, one byte per step (1: bad)
_CHAINS: dict[tuple[int, int, int, float, float], bytearray] = {}


def _chain(model: GilbertElliott, seed: int, entry: int, channel: int, step: int) -> bytearray:
    """The states of the chain of (seed, entry, channel) up to ``step`` at least (>= 0)."""
    key = (seed, entry, channel, model.p, model.r)
    states = _CHAINS.get(key)
    if states is None:
        states = _CHAINS[key] = bytearray()
    bad = bool(states[-1]) if states else False
    for k in range(len(states), step + 1):
        u = uniform(seed, entry, channel, k, _STATE)
        bad = u >= model.r if bad else u < model.p
        states.append(bad)
    return states


def state_at(model: GilbertElliott, seed: int, entry: int, channel: int, step: int) -> bool:
    """Whether the chain of (seed, entry, channel) is in the bad state at ``step`` (>= 0)."""
    return bool(_chain(model, seed, entry, channel, step)[step])


class Bursty:
    """The link model of ``bursty:``: a message is lost with ``loss_bad`` or ``loss_good`` as the
    entry's chain is in its bad or good state at the message's place in its stream."""

    Params = GilbertElliott
    plan_form = "params"  #: ``bursty: {p, r, ...}`` (``link_models``)
    on_mavlink = mavlink_in_lockstep = True

    def severity(self, p: GilbertElliott, period_s: float, staleness_s: float) -> float:
        return p.mean_loss

    def fate(self, p: GilbertElliott, m: MessageOnLink) -> Effect | None:
        bad = state_at(p, m.seed, m.entry, m.channel, m.chain)
        return LOST if m.uniform(DRAW) < (p.loss_bad if bad else p.loss_good) else None

    def fates(self, p: GilbertElliott, ms: StepsOnLink) -> Effects:
        chains = ms.chains
        lo, hi = int(chains[0]), int(chains[-1])
        states = _chain(p, ms.seed, ms.entry, ms.channel, hi)
        # (a copy of the states asked for: a view left alive would stop the chain growing)
        bad = np.frombuffer(states, dtype=np.uint8, count=hi + 1 - lo, offset=lo)[chains - lo] != 0
        return ms.where(ms.uniform(DRAW) < np.where(bad, p.loss_bad, p.loss_good), LOST)
