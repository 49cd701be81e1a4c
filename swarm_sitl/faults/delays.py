"""The link models that make messages late: ``delay_s`` (a fixed delay plus a uniform jitter),
``stall`` (held until the entry's end, then released at once) and ``reorder`` (held one period
with a probability, so it comes after the next one). The contract: ``link_model``."""

from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from swarm_sitl.faults.link_model import Effect, Effects, MessageOnLink, StepsOnLink
from swarm_sitl.faults.loss import DRAW

JITTER = 2  #: the salt of a message's jitter draw


class Delay:
    """Each message ``delay_s`` late, plus a draw uniform in ``[0, jitter_s]``."""

    plan_form = "delay"  #: ``delay_s: d`` and the entry's ``jitter_s`` (``link_models``)
    on_mavlink = True

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        delay_s: Annotated[float, Field(ge=0)]  #: [s]
        jitter_s: Annotated[float, Field(ge=0)] = 0.0  #: [s]

    def fate(self, p: Params, m: MessageOnLink) -> Effect:
        return Effect(delay_s=p.delay_s + p.jitter_s * m.uniform(JITTER))

    def severity(self, p: Params, period_s: float, staleness_s: float) -> float:
        """The mean over messages of each one's delay over the estimator's staleness, at most 1
        (an estimate past it is as good as lost): with ``a = delay_s / staleness_s`` and ``b =
        jitter_s / staleness_s``, the mean of ``min(1, a + b u)`` over ``u`` uniform in [0, 1]."""
        a, b = p.delay_s / staleness_s, p.jitter_s / staleness_s
        if a >= 1.0:
            return 1.0
        if a + b <= 1.0:
            return a + b / 2
        u = (1.0 - a) / b  # the share of messages that come before the staleness
        return a * u + b * u * u / 2 + (1.0 - u)

    def fates(self, p: Params, ms: StepsOnLink) -> Effects:
        none = np.zeros(len(ms.steps), dtype=bool)
        return Effects(none, none, p.delay_s + p.jitter_s * ms.uniform(JITTER), none)


class Stall:
    """Every message held until ``until_s`` (the entry's end), then released at once."""

    plan_form = "flag"  #: ``stall: true``, held until the entry's ``until_s`` (``link_models``)
    on_mavlink = True

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        until_s: Annotated[float, Field(gt=0)]  #: when the held messages go [s]

    def fate(self, p: Params, m: MessageOnLink) -> Effect:
        return Effect(delay_s=p.until_s - m.t_s)

    def severity(self, p: Params, period_s: float, staleness_s: float) -> float:
        return 1.0  # held past its use: a cut for the entry's window

    def fates(self, p: Params, ms: StepsOnLink) -> Effects:
        none = np.zeros(len(ms.steps), dtype=bool)
        return Effects(none, none, p.until_s - ms.t_s, none)


class Reorder:
    """Each message, with probability ``p``, held one period: it comes after the next one."""

    plan_form = "p"  #: ``reorder: p`` (``link_models``)
    on_mavlink = True

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        p: Annotated[float, Field(gt=0, le=1)]

    def fate(self, p: Params, m: MessageOnLink) -> Effect | None:
        return Effect(delay_s=m.period_s) if m.uniform(DRAW) < p.p else None

    def fates(self, p: Params, ms: StepsOnLink) -> Effects:
        return ms.where(ms.uniform(DRAW) < p.p, Effect(delay_s=ms.period_s))
