"""The link models that lose messages outright: ``drop`` (every one) and ``loss`` (each with a
probability, an independent draw per message). The contract: ``link_model``."""

from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from swarm_sitl.faults.link_model import Effect, Effects, MessageOnLink, StepsOnLink

DRAW = 1  #: the salt of a message's draw (shared by the one-draw models: loss, corrupt, reorder, duplicate)
LOST = Effect(lost=True)


class Drop:
    """Every message is lost."""

    plan_form = "flag"  #: ``drop: true`` (``link_models``)
    on_mavlink = mavlink_in_lockstep = True

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)

    def fate(self, p: Params, m: MessageOnLink) -> Effect:
        return LOST

    def severity(self, p: Params, period_s: float, staleness_s: float) -> float:
        return 1.0

    def fates(self, p: Params, ms: StepsOnLink) -> Effects:
        return ms.where(np.ones(len(ms.steps), dtype=bool), LOST)


class Chance:
    """A model that does ``EFFECT`` to each message with probability ``p`` (one draw of the
    message's, ``DRAW``): the base of ``Loss``, ``copies.Duplicate`` and ``copies.Corrupt``."""

    EFFECT = LOST
    plan_form = "p"  #: ``KEY: p`` (``link_models``)
    on_mavlink = True

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        p: Annotated[float, Field(gt=0, le=1)]  #: the probability it acts on a message

    def fate(self, p: Params, m: MessageOnLink) -> Effect | None:
        return self.EFFECT if m.uniform(DRAW) < p.p else None

    def fates(self, p: Params, ms: StepsOnLink) -> Effects:
        return ms.where(ms.uniform(DRAW) < p.p, self.EFFECT)


class Loss(Chance):
    """Each message is lost with probability ``p``."""

    mavlink_in_lockstep = True

    def severity(self, p: Chance.Params, period_s: float, staleness_s: float) -> float:
        return p.p
